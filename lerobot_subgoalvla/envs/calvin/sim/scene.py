"""The play-table scene: blocks, table (doors, button + LED, switch + lightbulb) and plane (docs/calvin.md
3.1-3.4, 3.8).

One code path for every :class:`~.assets.SceneSource`: the procedural desk and CALVIN's tables A-D are both
one multi-link body with CALVIN's joint names and link indices, found here by name.

Logic run once per control step after physics (spec 3.2), as calvin_env ``797142c``:

* button ``base__button``: pressed = joint > (lower + upper) / 2; each rising edge (not pressed at the
  previous control step, pressed now) toggles the button state and the LED follows;
* switch ``base__switch``: pressed = joint > (lower + upper) / 2; the switch state follows the level and the
  lightbulb changes only when the switch state changes;
* lights colour their link: LED green (0, 1, 0, 1), lightbulb yellow (1, 1, 0, 1), white when off.

Reset from ``scene_obs`` (spec 3.8, the fixed ``797142c`` order): slide, drawer; lights <- [4], [5]; button
joint <- [2] and button state := LED state; switch joint <- [3] and switch state := off; blocks <- pose. One
deliberate
difference: the button's "pressed at the previous step" memory is set from the reset joint value (CALVIN keeps
it from the previous episode, so a reset could fake or swallow a rising edge). Without ``scene_obs``: joints
0,
lights off and random block placement (spec 3.3).
"""

from __future__ import annotations

import itertools
import logging
import math
import tempfile

import numpy as np
import pybullet
from pybullet_utils.bullet_client import BulletClient

from lerobot_subgoalvla.envs.calvin.sim.assets import SceneSource, surface_array
from lerobot_subgoalvla.envs.calvin.sim.procedural_table import write_procedural_table

logger = logging.getLogger(__name__)

TABLE_LINKS = (
    "button_link",
    "switch_link",
    "slide_link",
    "drawer_link",
    "led_link",
    "light_link",
    "plank_link",
)
DOOR_JOINTS = ("base__slide", "base__drawer")  # scene_obs[0], [1]
LIGHT_LINKS = {"lightbulb": "light_link", "led": "led_link"}  # scene_obs[4], [5] in this order
LIGHT_COLOURS = {"lightbulb": (1.0, 1.0, 0.0, 1.0), "led": (0.0, 1.0, 0.0, 1.0)}
LIGHT_OFF = (1.0, 1.0, 1.0, 1.0)
JOINT_FRICTION_FORCE = 4.0  # doors and switch: VELOCITY_CONTROL v=0 (spec 3.2)
BUTTON_SPRING_FORCE = 4.0  # button: POSITION_CONTROL to 0
MAX_PLACEMENT_TRIES = 1000
SCENE_OBS_DIM = 24


def _quat_from_yaw(client: BulletClient, yaw: float) -> tuple[float, ...]:
    return client.getQuaternionFromEuler((0.0, 0.0, yaw))


class Scene:
    """Blocks, table and plane of one simulation, with the button/switch/light logic.

    Args:
        client: The simulation's own BulletClient (the robot is already loaded: body uids follow spec 3.1).
        source: What to load (:func:`~.assets.load_scene_source`).
    """

    def __init__(self, client: BulletClient, source: SceneSource) -> None:
        self.client = client
        self.source = source
        self.block_uids: dict[str, int] = {}
        self.table_uid = -1
        self.plane_uid = -1
        self.links: dict[str, int] = {}
        self.joints: dict[str, int] = {}
        self._limits: dict[str, tuple[float, float]] = {}
        self.light_states = {"lightbulb": 0, "led": 0}
        self.button_state = 0
        self.switch_state = 0
        self._button_was_pressed = False
        self._local_points: dict[str, tuple[int, tuple[float, float, float]]] = {}
        self.surfaces = surface_array(source)

    # ------------------------------------------------------------------ loading
    def load(self) -> None:
        """Blocks in slot order, then the table, then the plane (spec 3.1: uids 2-4, 5, 6)."""
        c = self.client
        calvin_blocks = bool(self.source.blocks) and self.source.blocks[0].urdf is not None
        load_poses = calvin_load_poses(self.source.surfaces, len(self.source.blocks)) if calvin_blocks else []
        for slot, block in enumerate(self.source.blocks):
            if block.urdf is not None:  # CALVIN's scenes: where a fresh calvin_env loads them
                position, yaw = load_poses[slot]
                orientation = c.getQuaternionFromEuler((0.0, 0.0, yaw))
                uid = c.loadURDF(
                    str(block.urdf), position, orientation, globalScaling=self.source.global_scaling
                )
            else:
                parking = (2.0 + slot, 2.0, 0.5)  # our procedural blocks: out of the way until reset
                half = [s / 2 for s in block.size]
                shape = c.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half)
                visual = c.createVisualShape(pybullet.GEOM_BOX, halfExtents=half, rgbaColor=block.rgba)
                uid = c.createMultiBody(1.0, shape, visual, parking)
                c.changeDynamics(
                    uid, -1, lateralFriction=0.7, spinningFriction=0.001, rollingFriction=0.0, restitution=0.0
                )
            self.block_uids[block.name] = uid
        if self.source.table_urdf is None:
            with tempfile.TemporaryDirectory(prefix="subgoalvla_table_") as tmp:
                self.table_uid = c.loadURDF(str(write_procedural_table(tmp)), useFixedBase=True)
        else:
            self.table_uid = c.loadURDF(
                str(self.source.table_urdf), useFixedBase=True, globalScaling=self.source.global_scaling
            )
        self.plane_uid = c.loadURDF(str(self.source.plane_urdf))
        self._index_table()
        self._set_motors()
        self._resolve_points()

    def _index_table(self) -> None:
        c = self.client
        for j in range(c.getNumJoints(self.table_uid)):
            info = c.getJointInfo(self.table_uid, j)
            self.joints[info[1].decode()] = j
            self.links[info[12].decode()] = j
        missing = [name for name in TABLE_LINKS if name not in self.links]
        if missing:
            raise ValueError(
                f"table URDF {self.source.table_urdf}: links {missing} not found (not a CALVIN table)"
            )
        if [self.links[name] for name in TABLE_LINKS] != list(range(7)):
            raise ValueError(f"table links are not in CALVIN's index order {TABLE_LINKS}: {self.links}")
        self._limits = {name: c.getJointInfo(self.table_uid, j)[8:10] for name, j in self.joints.items()}

    def _set_motors(self) -> None:
        c = self.client
        for name in (*DOOR_JOINTS, "base__switch"):
            c.setJointMotorControl2(
                self.table_uid,
                self.joints[name],
                pybullet.VELOCITY_CONTROL,
                targetVelocity=0,
                force=JOINT_FRICTION_FORCE,
            )
        c.setJointMotorControl2(
            self.table_uid,
            self.joints["base__button"],
            pybullet.POSITION_CONTROL,
            targetPosition=0.0,
            force=BUTTON_SPRING_FORCE,
        )

    def _resolve_points(self) -> None:
        """Turn the source's world-aligned point offsets into link-local points (joints are at 0 after
        loading)."""
        c = self.client
        for name, (link_name, offset) in self.source.points.items():
            link = self.links[link_name]
            pos, orn = c.getLinkState(self.table_uid, link, computeForwardKinematics=True)[4:6]
            inv_pos, inv_orn = c.invertTransform((0, 0, 0), orn)
            local, _ = c.multiplyTransforms(inv_pos, inv_orn, offset, (0, 0, 0, 1))
            self._local_points[name] = (link, local)

    # ------------------------------------------------------------------ privileged geometry
    @property
    def block_names(self) -> tuple[str, ...]:
        """Block names in scene_obs slot order."""
        return tuple(block.name for block in self.source.blocks)

    @property
    def point_names(self) -> tuple[str, ...]:
        """Names accepted by :meth:`handle_position`."""
        return tuple(self._local_points)

    def handle_position(self, name: str) -> np.ndarray:
        """World position (3,) of a named point that moves with its link: ``drawer_handle`` (centre of the
        bar),
        ``slide_handle``, ``button_top``, ``switch_lever``, ``led``, ``lightbulb``."""
        if name not in self._local_points:
            raise ValueError(f"unknown point {name!r}; known: {self.point_names}")
        link, local = self._local_points[name]
        pos, orn = self.client.getLinkState(self.table_uid, link, computeForwardKinematics=True)[4:6]
        return np.array(self.client.multiplyTransforms(pos, orn, local, (0, 0, 0, 1))[0])

    def joint_state(self, joint: str) -> float:
        """Position of a table joint (m), e.g. ``base__drawer``."""
        return float(self.client.getJointState(self.table_uid, self.joints[joint])[0])

    def joint_limits(self, joint: str) -> tuple[float, float]:
        """(lower, upper) world limits of a table joint."""
        return self._limits[joint]

    # ------------------------------------------------------------------ reset
    def reset(self, scene_obs: np.ndarray | None, np_random: np.random.Generator | None) -> None:
        """Reset from ``scene_obs`` (24,) or, when ``None``, to closed doors, lights off and random blocks."""
        if scene_obs is None:
            if np_random is None:
                raise ValueError(
                    "reset without scene_obs places blocks randomly: pass np_random (a numpy Generator)"
                )
            values = np.zeros(SCENE_OBS_DIM)
        else:
            values = np.asarray(scene_obs, dtype=np.float64)
            if values.shape != (SCENE_OBS_DIM,) or not np.all(np.isfinite(values)):
                raise ValueError(f"scene_obs must be a finite array of shape (24,), got shape {values.shape}")
        c = self.client
        for i, joint in enumerate(DOOR_JOINTS):
            c.resetJointState(self.table_uid, self.joints[joint], float(values[i]))
        self._set_light("lightbulb", int(values[4] > 0.5))
        self._set_light("led", int(values[5] > 0.5))
        c.resetJointState(self.table_uid, self.joints["base__button"], float(values[2]))
        self.button_state = self.light_states["led"]
        self._button_was_pressed = self._pressed("base__button")
        c.resetJointState(self.table_uid, self.joints["base__switch"], float(values[3]))
        self.switch_state = 0
        if scene_obs is None:
            self._place_blocks_randomly(np_random)
        else:
            for slot, uid in enumerate(self.block_uids.values()):
                pose = values[6 + 6 * slot : 12 + 6 * slot]
                c.resetBasePositionAndOrientation(
                    uid, pose[:3].tolist(), c.getQuaternionFromEuler(pose[3:].tolist())
                )
                c.resetBaseVelocity(uid, (0, 0, 0), (0, 0, 0))

    def _place_blocks_randomly(self, rng: np.random.Generator) -> None:
        """Each block uniformly in a uniformly chosen surface box, yaw U(-pi, pi); resample until no block
        touches
        another (spec 3.3: up to 1000 tries, one physics step each)."""
        c = self.client
        names = list(self.surfaces)
        for _ in range(MAX_PLACEMENT_TRIES):
            for uid in self.block_uids.values():
                low, high = self.surfaces[names[int(rng.integers(len(names)))]]
                pos = rng.uniform(low, high)
                yaw = float(rng.uniform(-math.pi, math.pi))
                c.resetBasePositionAndOrientation(uid, pos.tolist(), _quat_from_yaw(c, yaw))
                c.resetBaseVelocity(uid, (0, 0, 0), (0, 0, 0))
            c.stepSimulation()
            if not any(
                c.getContactPoints(bodyA=a, bodyB=b)
                for a, b in itertools.combinations(self.block_uids.values(), 2)
            ):
                return
        logger.error("could not place the blocks without contacts in %d tries", MAX_PLACEMENT_TRIES)

    # ------------------------------------------------------------------ per-step logic
    def _pressed(self, joint: str) -> bool:
        lower, upper = self._limits[joint]
        return self.joint_state(joint) > (lower + upper) / 2

    def _set_light(self, name: str, state: int) -> None:
        self.light_states[name] = state
        colour = LIGHT_COLOURS[name] if state else LIGHT_OFF
        self.client.changeVisualShape(self.table_uid, self.links[LIGHT_LINKS[name]], rgbaColor=colour)

    def step(self) -> None:
        """Button (rising edge toggles LED) and switch (level drives the lightbulb), once per control step."""
        pressed = self._pressed("base__button")
        if pressed and not self._button_was_pressed:
            self.button_state = 1 - self.button_state
            self._set_light("led", self.button_state)
        self._button_was_pressed = pressed
        switch_on = int(self._pressed("base__switch"))
        if switch_on != self.switch_state:
            self.switch_state = switch_on
            self._set_light("lightbulb", switch_on)

    # ------------------------------------------------------------------ observation / info
    def observation(self) -> np.ndarray:
        """scene_obs (24,) float64 (spec 1.5): slide, drawer, button, switch, lightbulb, LED, 3 x block
        pose."""
        c = self.client
        values = [
            self.joint_state("base__slide"),
            self.joint_state("base__drawer"),
            self.joint_state("base__button"),
            self.joint_state("base__switch"),
            self.light_states["lightbulb"],
            self.light_states["led"],
        ]
        for uid in self.block_uids.values():
            pos, orn = c.getBasePositionAndOrientation(uid)
            values.extend([*pos, *c.getEulerFromQuaternion(orn)])
        return np.array(values, dtype=np.float64)

    def info(self) -> dict:
        """CALVIN's ``scene_info`` (spec 2.1); contacts of the last physics sub-step."""
        c = self.client
        movable = {}
        for name, uid in self.block_uids.items():
            pos, orn = c.getBasePositionAndOrientation(uid)
            lin, ang = c.getBaseVelocity(uid)
            movable[name] = {
                "current_pos": pos,
                "current_orn": orn,
                "current_lin_vel": lin,
                "current_ang_vel": ang,
                "contacts": c.getContactPoints(bodyA=uid),
                "uid": uid,
            }
        table = {
            "uid": self.table_uid,
            "links": {"base_link": -1, **{name: self.links[name] for name in TABLE_LINKS}},
            "contacts": c.getContactPoints(bodyA=self.table_uid),
        }
        return {
            "fixed_objects": {"table": table},
            "movable_objects": movable,
            "doors": {joint: {"current_state": self.joint_state(joint)} for joint in DOOR_JOINTS},
            "lights": {name: {"logical_state": state} for name, state in self.light_states.items()},
            "buttons": {
                "base__button": {
                    "joint_state": self.joint_state("base__button"),
                    "logical_state": self.button_state,
                }
            },
            "switches": {
                "base__switch": {
                    "joint_state": self.joint_state("base__switch"),
                    "logical_state": self.switch_state,
                }
            },
        }


def calvin_load_poses(
    surfaces: dict[str, tuple[tuple[float, ...], tuple[float, ...]]], num_blocks: int, seed: int = 0
) -> list[tuple[np.ndarray, float]]:
    """Where calvin_env puts its blocks when it loads a scene: ``(position (3,), yaw)`` per block, slot order.

    CALVIN's scene configs load every block at ``initial_pos: any`` / ``initial_orn: any``, drawn at
    construction from the env's generator seeded with its config seed 0 (gymnasium-style ``np_random(0)``, a
    PCG64 ``numpy.random.Generator``): per block a surface by ``choice`` over the scene's surfaces in config
    order, a position ``uniform(low, high)`` in it, then euler angles ``uniform([0, 0, -pi], [0, 0, pi])``.
    Resets place the blocks anew, but where they were loaded shapes pybullet's contact bookkeeping, so
    bit-exact agreement with a fresh calvin_env needs the same load poses (docs/calvin.md 3.1).
    """
    rng = np.random.default_rng(seed)
    names = list(surfaces)
    poses = []
    for _ in range(num_blocks):
        low, high = surfaces[str(rng.choice(names))]
        position = rng.uniform(low, high)
        yaw = float(rng.uniform([0.0, 0.0, -np.pi], [0.0, 0.0, np.pi])[2])
        poses.append((position, yaw))
    return poses
