"""``CalvinSimulation``: CALVIN's play-table simulator on its own pybullet client (docs/calvin.md section 3).

One instance = one ``BulletClient`` in DIRECT mode (no global pybullet connection), so several simulations
live side by side in one process (vector envs, expert + evaluation). Physics as CALVIN (spec 3.7): gravity
-9.8, ``setTimeStep(1/240)``, default solver, ``deterministicOverlappingPairs`` at Bullet's default 0 (what
CALVIN ends up with, see ``__init__``), 8 physics sub-steps per 30 Hz control step. Loading order and body
uids as spec 3.1: robot 0, visual base cylinder 1, blocks 2-4 (slot order), table 5, plane 6.

``step(action)`` = apply the action to the robot (IK + motor targets + gripper), 8 x ``stepSimulation``, then
the button/switch/light logic. Unlike CALVIN's ``env.step`` it does not render: call :meth:`render_cameras`
when images are needed (an expert can run without rendering). ``reset`` follows spec 3.8: scene first (see
:mod:`.scene`), then the robot (joints from robot_obs[7:14], fingers from robot_obs[6] / 2, target pose :=
measured TCP), then one ``stepSimulation`` without button/switch logic.

Example:
    >>> sim = CalvinSimulation("procedural", cameras=False)
    >>> sim.reset(np_random=np.random.default_rng(0))
    >>> sim.step(np.array([1.0, 0, 0, 0, 0, 0, 1]))  # 2 cm towards +x, gripper open
    >>> sim.robot_obs().shape, sim.scene_obs().shape
    ((15,), (24,))
"""

from __future__ import annotations

import weakref
from pathlib import Path

import numpy as np
import pybullet
from pybullet_utils.bullet_client import BulletClient

from lerobot_subgoalvla.envs.calvin.sim.assets import load_scene_source
from lerobot_subgoalvla.envs.calvin.sim.cameras import Cameras, check_renderer, load_egl_plugin
from lerobot_subgoalvla.envs.calvin.sim.egl_devices import select_egl_device
from lerobot_subgoalvla.envs.calvin.sim.robot import ActionMode, PandaRobot
from lerobot_subgoalvla.envs.calvin.sim.scene import Scene
from lerobot_subgoalvla.envs.calvin.sim.stdio import quiet_c_output

PHYSICS_HZ = 240
CONTROL_HZ = 30
ACTION_REPEAT = PHYSICS_HZ // CONTROL_HZ  # 8 sub-steps per control step
ROBOT_OBS_DIM = 15


def _disconnect(client: BulletClient) -> None:
    if client._client >= 0:  # BulletClient sets it to -1 on disconnect
        with quiet_c_output():  # the EGL plugin says goodbye on fd 1
            client.disconnect()


class CalvinSimulation:
    """CALVIN's play table (procedural desk or CALVIN's scenes A-D) with a Panda, cameras and the info dict.

    Args:
        scene: ``"procedural"`` (default, no files needed) or ``"calvin_A"`` .. ``"calvin_D"``.
        assets_dir: A clone of mees/calvin_env (with ``conf/`` and ``data/``); required for ``calvin_*``.
        static_size: Static camera width = height (CALVIN 200).
        gripper_size: Gripper camera width = height (CALVIN 84).
        cameras: Build the cameras; ``False`` makes :meth:`render_cameras` raise (physics-only use).
        action_mode: ``"relative"`` (CALVIN rel_actions, 7-d in [-1, 1]) or ``"absolute"`` (TCP pos, euler,
            gripper).
        renderer: ``"tiny"`` (pybullet's CPU TinyRenderer) or ``"egl"`` (OpenGL via the EGL plugin, as
            CALVIN's data; see :mod:`.cameras`).
        egl_cuda_device: With ``renderer="egl"``: render on the EGL device of this CUDA GPU (calvin_env's
            choice; :mod:`.egl_devices`); None keeps ``EGL_VISIBLE_DEVICES`` (default device 0).

    Attributes:
        client: The BulletClient (privileged access for the expert).
        robot: :class:`~.robot.PandaRobot` (``uid``, ``target_pos``, ``tcp_pose()``...).
        scene: :class:`~.scene.Scene` (``table_uid``, ``links``, ``block_uids``, ``surfaces``,
            ``handle_position(name)``...).
    """

    def __init__(
        self,
        scene: str = "procedural",
        assets_dir: str | Path | None = None,
        static_size: int = 200,
        gripper_size: int = 84,
        cameras: bool = True,
        action_mode: ActionMode = "relative",
        renderer: str = "tiny",
        egl_cuda_device: int | None = None,
    ) -> None:
        check_renderer(renderer)
        if egl_cuda_device is not None and renderer != "egl":
            raise ValueError(f"egl_cuda_device={egl_cuda_device} needs renderer='egl', got {renderer!r}")
        source = load_scene_source(scene, assets_dir)  # validates names and files before connecting
        self.scene_name = scene
        with quiet_c_output():  # pybullet's "argv[0]=" on connect
            self.client = BulletClient(connection_mode=pybullet.DIRECT)
        # Disconnect at garbage collection or interpreter exit, before pybullet itself is torn down.
        self._finalizer = weakref.finalize(self, _disconnect, self.client)
        try:
            c = self.client
            c.resetSimulation()
            c.setGravity(0, 0, -9.8)
            c.setTimeStep(1.0 / PHYSICS_HZ)
            if cameras and renderer == "egl":
                select_egl_device(egl_cuda_device)  # the plugin ends the process on a device it lacks
                load_egl_plugin(c)  # before the first body: loaded later it renders only the background
            # No deterministicOverlappingPairs: calvin_env sets it to 1 in initialize_bullet, but its load()
            # calls resetSimulation afterwards, which restores Bullet's default (0). CALVIN runs with 0, and
            # contact-rich runs diverge when the flag differs (spec 3.7).
            self.robot = PandaRobot(c, source.robot, action_mode)
            self.robot.load()
            self.scene = Scene(c, source)
            self.scene.load()
            self.robot.reset()
            self.cameras = Cameras(c, static_size, gripper_size, renderer) if cameras else None
        except Exception:
            self.close()
            raise

    @property
    def block_names(self) -> tuple[str, ...]:
        """Block names in scene_obs slot order (e.g. ``("block_red", "block_blue", "block_pink")`` for D)."""
        return self.scene.block_names

    @property
    def action_mode(self) -> ActionMode:
        """``"relative"`` or ``"absolute"``."""
        return self.robot.action_mode

    def reset(
        self,
        robot_obs: np.ndarray | None = None,
        scene_obs: np.ndarray | None = None,
        np_random: np.random.Generator | None = None,
    ) -> None:
        """Reset the scene and the robot (spec 3.8).

        Args:
            robot_obs: (15,) state to restore (only [6] and [7:14] are used); ``None`` = default arm pose,
                open.
            scene_obs: (24,) state to restore; ``None`` = doors closed, lights off, random blocks (needs
                ``np_random``).
            np_random: Generator for the random block placement (the caller's seeded ``np_random``).

        Raises:
            ValueError: Wrong shape or non-finite values, or random placement without ``np_random``.
        """
        if robot_obs is not None:
            robot_obs = np.asarray(robot_obs, dtype=np.float64)
            if robot_obs.shape != (ROBOT_OBS_DIM,) or not np.all(np.isfinite(robot_obs)):
                raise ValueError(
                    f"robot_obs must be a finite array of shape (15,), got shape {robot_obs.shape}"
                )
        self.scene.reset(scene_obs, np_random)
        self.robot.reset(robot_obs)
        self.client.stepSimulation()

    def step(self, action: np.ndarray) -> None:
        """Apply one 30 Hz action (7,), run 8 physics sub-steps, then the button/switch logic (spec 3.7).

        Raises:
            ValueError: ``action`` is not a finite array of shape (7,).
        """
        self.robot.apply_action(action)
        for _ in range(ACTION_REPEAT):
            self.client.stepSimulation()
        self.scene.step()

    def robot_obs(self) -> np.ndarray:
        """(15,) float64, spec 1.4."""
        return self.robot.observation()

    def scene_obs(self) -> np.ndarray:
        """(24,) float64, spec 1.5 (block slots in :attr:`block_names` order)."""
        return self.scene.observation()

    def render_cameras(self) -> dict[str, np.ndarray]:
        """``{"static": (S, S, 3) uint8, "gripper": (G, G, 3) uint8}`` of the current state."""
        if self.cameras is None:
            raise RuntimeError(
                "this CalvinSimulation was built with cameras=False; build it with cameras=True"
            )
        position, rotation = self.robot.camera_pose()
        return {
            "static": self.cameras.render_static(),
            "gripper": self.cameras.render_gripper(position, rotation),
        }

    def get_info(self) -> dict:
        """CALVIN's info dict ``{"robot_info": ..., "scene_info": ...}`` (spec 2.1)."""
        return {"robot_info": self.robot.info(), "scene_info": self.scene.info()}

    def close(self) -> None:
        """Disconnect the physics client (idempotent)."""
        self._finalizer()

    def __enter__(self) -> CalvinSimulation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
