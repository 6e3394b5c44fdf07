"""CALVIN's static and gripper RGB cameras (docs/calvin.md section 3.6), rendered on the CPU with
TinyRenderer.

| camera  | default size | vertical fov | near / far | pose |
|---------|--------------|--------------|------------|------|
| static  | 200 x 200    | 10 deg       | 0.01 / 10  | fixed, from ``conf/cameras/cameras/static.yaml`` |
| gripper | 84 x 84      | 75 deg       | 0.01 / 2   | camera frame: eye = origin, target = eye + y, up = -z |

Two renderers (``renderer=``): ``"tiny"``, pybullet's CPU TinyRenderer (``ER_TINY_RENDERER``), and ``"egl"``,
OpenGL through pybullet's ``eglRenderer`` plugin (``ER_BULLET_HARDWARE_OPENGL``), which is how CALVIN rendered
its dataset and evaluates. Their images differ (lighting, specular highlights; CALVIN README FAQ). EGL needs
an EGL driver: NVIDIA's on a GPU (``EGL_VISIBLE_DEVICES`` picks the device), Mesa's llvmpipe on a CPU. The
plugin must be loaded on a client before any body exists (``load_egl_plugin``); afterwards every image of that
client uses it. No custom lights or shadows, as CALVIN. Images are RGB uint8 (H, W, 3).
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pybullet
from pybullet_utils.bullet_client import BulletClient

from lerobot_subgoalvla.envs.calvin.protocol import RENDERERS
from lerobot_subgoalvla.envs.calvin.sim.stdio import quiet_c_output

_PYBULLET_RENDERER = {"tiny": pybullet.ER_TINY_RENDERER, "egl": pybullet.ER_BULLET_HARDWARE_OPENGL}

STATIC_EYE = (2.871459009488717, -2.166602199425597, 2.555159848480571)
STATIC_TARGET = (-0.026242351159453392, -0.0302329882979393, 0.3920000493526459)
STATIC_UP = (0.4041403970338857, 0.22629790978217404, 0.8862616969685161)
STATIC_FOV, STATIC_NEAR, STATIC_FAR = 10.0, 0.01, 10.0
GRIPPER_FOV, GRIPPER_NEAR, GRIPPER_FAR = 75.0, 0.01, 2.0


def check_renderer(renderer: str) -> str:
    """``renderer`` if it names one of ``RENDERERS``; ValueError naming the allowed values otherwise."""
    if renderer not in RENDERERS:
        raise ValueError(f"renderer={renderer!r} is not valid; use one of: {', '.join(RENDERERS)}")
    return renderer


def load_egl_plugin(client: BulletClient) -> int:
    """Load pybullet's ``eglRenderer`` plugin on ``client`` (call it before the first body is loaded).

    Returns the plugin id. Raises RuntimeError when the plugin or an EGL driver is missing.
    """
    spec = importlib.util.find_spec("eglRenderer")
    if spec is None or spec.origin is None:
        raise RuntimeError(
            "renderer='egl': this pybullet build has no eglRenderer plugin; use renderer='tiny'"
        )
    with quiet_c_output():
        plugin = client.loadPlugin(spec.origin, "_eglRendererPlugin")
    if plugin < 0:
        raise RuntimeError(
            "renderer='egl': pybullet could not load its EGL plugin (no EGL driver? on Debian: apt-get "
            "install libegl1 libegl-mesa0 libgl1-mesa-dri); use renderer='tiny'"
        )
    return plugin


class Cameras:
    """Renders both cameras of one simulation.

    Args:
        client: The simulation's BulletClient (with the EGL plugin loaded for ``renderer="egl"``).
        static_size: Width = height of the static image (CALVIN: 200).
        gripper_size: Width = height of the gripper image (CALVIN: 84).
        renderer: ``"tiny"`` or ``"egl"`` (module docstring).
    """

    def __init__(
        self, client: BulletClient, static_size: int = 200, gripper_size: int = 84, renderer: str = "tiny"
    ) -> None:
        for name, size in (("static_size", static_size), ("gripper_size", gripper_size)):
            if not isinstance(size, int) or size < 1:
                raise ValueError(f"{name} must be a positive int, got {size!r}")
        self.renderer = check_renderer(renderer)
        self._egl_sizes_seen: set[int] = set()
        self.client = client
        self.static_size = static_size
        self.gripper_size = gripper_size
        self._static_view = client.computeViewMatrix(STATIC_EYE, STATIC_TARGET, STATIC_UP)
        self._static_proj = client.computeProjectionMatrixFOV(STATIC_FOV, 1.0, STATIC_NEAR, STATIC_FAR)
        self._gripper_proj = client.computeProjectionMatrixFOV(GRIPPER_FOV, 1.0, GRIPPER_NEAR, GRIPPER_FAR)

    def _render(self, size: int, view: tuple[float, ...], proj: tuple[float, ...]) -> np.ndarray:
        if self.renderer == "egl" and size not in self._egl_sizes_seen:
            self._egl_sizes_seen.add(size)
            with quiet_c_output():  # the plugin prints its GL vendor for each new framebuffer size
                return self._render(size, view, proj)
        _, _, rgba, _, _ = self.client.getCameraImage(
            size,
            size,
            viewMatrix=view,
            projectionMatrix=proj,
            renderer=_PYBULLET_RENDERER[self.renderer],
            flags=pybullet.ER_NO_SEGMENTATION_MASK,
        )
        if not isinstance(rgba, np.ndarray):
            # pybullet built without numpy (the default for a source build in an isolated environment) returns
            # a tuple of ints; bytes() converts it ~6x faster than np.asarray. See docs/calvin_simulator.md.
            rgba = np.frombuffer(bytes(rgba), dtype=np.uint8)
        return np.asarray(rgba, dtype=np.uint8).reshape(size, size, 4)[:, :, :3].copy()  # (H, W, 3)

    def render_static(self) -> np.ndarray:
        """Static camera image (static_size, static_size, 3) uint8."""
        return self._render(self.static_size, self._static_view, self._static_proj)

    def render_gripper(self, position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
        """Gripper camera image (gripper_size, gripper_size, 3) uint8 from the camera frame's world pose.

        Args:
            position: Camera frame origin (3,) in the world.
            rotation: Camera frame rotation (3, 3); columns are the frame's x, y, z axes in the world.
        """
        view = self.client.computeViewMatrix(
            position.tolist(), (position + rotation[:, 1]).tolist(), (-rotation[:, 2]).tolist()
        )
        return self._render(self.gripper_size, view, self._gripper_proj)
