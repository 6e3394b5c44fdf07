"""Subgoal traces made visible (paper figure 7): predicted proprioceptive traces drawn as ghost robots.

SubgoalVLA's planner predicts a trace of future robot states, ``(M, 15)`` in CALVIN's ``robot_obs`` layout
(spec 1.4; the data contract's ``observation.subgoal_trace`` with M = 8). To see what the plan means, each
trace state is shown as a translucent copy of the robot in the static camera's view:

1. save the PyBullet state (``saveState``),
2. for each trace state m, put the simulation's own robot in that pose (arm joints ``robot_obs[7:14]``, each
   finger ``robot_obs[6] / 2``, as a CALVIN reset does, spec 3.8), render the static camera with its
   segmentation mask and keep the robot's pixels,
3. restore the saved state (``restoreState``), so the simulation continues exactly as if nothing was drawn,
4. alpha-blend the ghosts over the current frame, the farthest first, opacity fading from ``max_alpha``
   (m = 0, the nearest subgoal) to ``min_alpha`` (m = M - 1), tinted along a matplotlib colormap so that the
   order is readable.

Physics is never stepped, so no motor target, button logic or contact changes. Images are (H, W, 3) uint8.

Example:
    >>> overlay = render_trace(env.simulation, predicted_trace)  # (200, 200, 3) uint8
    >>> write_trace_media([overlay_0, overlay_1, ...], "rollout.mp4")
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import matplotlib
import numpy as np
import pybullet
from lerobot.utils.io_utils import write_video
from PIL import Image

from lerobot_subgoalvla.calvin_vocab import CALVIN_FPS
from lerobot_subgoalvla.envs.calvin.sim import cameras
from lerobot_subgoalvla.envs.calvin.sim.robot import ARM_JOINTS
from lerobot_subgoalvla.envs.calvin.sim.simulation import CalvinSimulation

logger = logging.getLogger(__name__)

# Dimension legend: M = trace length, H = W = static image side, 15 = robot_obs.
ROBOT_OBS_DIM = 15
#: Share of the colormap tint in a ghost's colour (the rest is the robot's rendered shading).
TINT = 0.5


def render_trace(
    sim: CalvinSimulation,
    trace: np.ndarray,
    frame: np.ndarray | None = None,
    *,
    max_alpha: float = 0.7,
    min_alpha: float = 0.2,
    colormap: str = "viridis",
) -> np.ndarray:
    """Draw ``trace`` as ghost robots over the static-camera image of ``sim``'s current state.

    Args:
        sim: The simulation (its state is restored exactly before returning).
        trace: ``(M, 15)`` robot states in ``robot_obs`` units (un-normalised), nearest subgoal first.
        frame: ``(H, W, 3)`` uint8 image to draw on; default: the static camera's current image.
        max_alpha: Opacity of the nearest ghost (m = 0).
        min_alpha: Opacity of the farthest ghost (m = M - 1).
        colormap: matplotlib colormap tinting the ghosts from near to far.

    Returns:
        ``(H, W, 3)`` uint8 overlay.

    Raises:
        ValueError: ``trace`` is not a finite ``(M, 15)`` array, ``frame`` does not match the static camera,
            or the alphas are not in [0, 1].
    """
    trace = _checked_trace(trace)
    if not 0.0 <= min_alpha <= 1.0 or not 0.0 <= max_alpha <= 1.0:
        raise ValueError(f"max_alpha={max_alpha} and min_alpha={min_alpha} must lie in [0, 1]")
    if sim.cameras is None:
        raise ValueError("render_trace needs a CalvinSimulation built with cameras=True")
    size = sim.cameras.static_size
    if frame is None:
        frame = sim.cameras.render_static()
    if frame.shape != (size, size, 3) or frame.dtype != np.uint8:
        raise ValueError(
            f"frame must be a ({size}, {size}, 3) uint8 static image, got {frame.shape} {frame.dtype}"
        )
    ghosts = _ghost_layers(sim, trace, size)  # (M, H, W, 3) uint8, (M, H, W) bool
    alphas = np.linspace(max_alpha, min_alpha, len(trace))
    tints = matplotlib.colormaps[colormap](np.linspace(0.0, 1.0, len(trace)))[:, :3] * 255.0  # (M, 3)
    out = frame.astype(np.float64)
    for m in reversed(range(len(trace))):  # farthest first, so nearer ghosts end on top
        rgb, mask = ghosts[0][m], ghosts[1][m]
        colour = (1.0 - TINT) * rgb[mask] + TINT * tints[m]
        out[mask] = (1.0 - alphas[m]) * out[mask] + alphas[m] * colour
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def _ghost_layers(sim: CalvinSimulation, trace: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Render the robot alone in each trace pose; the sim's state is saved before and restored after."""
    client, robot = sim.client, sim.robot
    view = client.computeViewMatrix(cameras.STATIC_EYE, cameras.STATIC_TARGET, cameras.STATIC_UP)
    proj = client.computeProjectionMatrixFOV(cameras.STATIC_FOV, 1.0, cameras.STATIC_NEAR, cameras.STATIC_FAR)
    rgbs = np.zeros((len(trace), size, size, 3), dtype=np.uint8)
    masks = np.zeros((len(trace), size, size), dtype=bool)
    saved = client.saveState()
    try:
        for m, state in enumerate(trace):
            for joint, angle in zip(ARM_JOINTS, state[7:14], strict=True):
                client.resetJointState(robot.uid, joint, float(angle))
            for joint in robot.spec.finger_joints:
                client.resetJointState(robot.uid, joint, float(state[6]) / 2)
            _, _, rgba, _, seg = client.getCameraImage(
                size, size, viewMatrix=view, projectionMatrix=proj, renderer=pybullet.ER_TINY_RENDERER
            )
            if not isinstance(rgba, np.ndarray):  # pybullet built without numpy returns tuples
                rgba = np.frombuffer(bytes(rgba), dtype=np.uint8)
            rgbs[m] = np.asarray(rgba, dtype=np.uint8).reshape(size, size, 4)[:, :, :3]
            masks[m] = np.asarray(seg, dtype=np.int64).reshape(size, size) == robot.uid
    finally:
        client.restoreState(stateId=saved)
        client.removeState(saved)
    return rgbs, masks


def _checked_trace(trace: np.ndarray) -> np.ndarray:
    array = np.asarray(trace, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != ROBOT_OBS_DIM or len(array) == 0:
        raise ValueError(
            f"trace must have shape (M, {ROBOT_OBS_DIM}) with M >= 1 (robot_obs rows), got {array.shape}"
        )
    if not np.all(np.isfinite(array)):
        raise ValueError("trace contains NaN or inf")
    return array


def write_trace_media(frames: Sequence[np.ndarray], path: str | Path, fps: int = CALVIN_FPS) -> Path:
    """Save overlay frames: ``.mp4`` as a video (LeRobot's ``write_video``), ``.png`` as a side-by-side strip.

    Args:
        frames: ``(H, W, 3)`` uint8 images of one size, e.g. :func:`render_trace` outputs along a rollout.
        path: Output file; its suffix (``.mp4`` or ``.png``) picks the format; parent folders are created.
        fps: Video frame rate (CALVIN's control rate by default).

    Returns:
        The written path.
    """
    path = Path(path)
    if path.suffix not in (".mp4", ".png"):
        raise ValueError(f"{path}: use a .mp4 (video) or .png (strip of frames) file name")
    if not frames:
        raise ValueError("write_trace_media got no frames")
    stack = np.stack([np.asarray(f) for f in frames])  # (N, H, W, 3)
    if stack.ndim != 4 or stack.shape[-1] != 3 or stack.dtype != np.uint8:
        raise ValueError(
            f"frames must be (H, W, 3) uint8 images of one size, got {stack.shape} {stack.dtype}"
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".png":
        Image.fromarray(np.concatenate(list(stack), axis=1)).save(path)  # (H, N * W, 3)
    else:
        write_video(str(path), stack, fps)
    logger.info("wrote %d trace frame(s) to %s", len(stack), path)
    return path
