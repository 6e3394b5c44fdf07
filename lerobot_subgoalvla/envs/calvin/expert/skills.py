"""Motion primitives and privileged geometry for the scripted CALVIN expert.

The expert drives the TCP with CALVIN's *relative* actions (spec 1.6): ``rel[0:3] = dpos / 0.02`` and
``rel[3:6] = wrap(deuler) / 0.05``, each clipped to [-1, 1], gripper exactly +1 (open) / -1 (close). The sim
adds these deltas to a target pose it keeps (spec 3.5), while this module computes them from the *measured*
TCP pose (the joints' current forward kinematics; ``robot_obs[0:6]`` reports it one physics sub-step late),
like a teleoperator reacting to the robot: a proportional controller toward the current waypoint,
speed-capped so that demonstrations look like teleoperation rather than jumps.

Skills are Python generators that yield one (7,) action per control step and read the simulator's state
between yields (closed loop): ``yield from servo(...)`` moves to a waypoint, ``yield from hold(...)`` waits
with a gripper command. A skill that cannot reach its waypoint in time raises :class:`ExpertFailureError`.

Geometry that the seams do not publish (handle positions) is measured from the sim's pybullet client with ray
casts against the table body, so the same code serves the procedural scene and CALVIN's scenes A-D.

Legend: positions (3,) in world metres; eulers (3,) extrinsic xyz in radians (spec 0); actions (7,).
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from lerobot_subgoalvla.envs.calvin.sim.simulation import CalvinSimulation

#: Scale of CALVIN's relative actions (spec 1.6): full scale = 2 cm and 0.05 rad per 30 Hz step.
POS_SCALE = 0.02
ROT_SCALE = 0.05
GRIPPER_OPEN = 1.0
GRIPPER_CLOSE = -1.0
#: TCP pointing straight down (roll pi, pitch 0); yaw is chosen per skill.
DOWN_ROLL = np.pi

Action = np.ndarray
Skill = Generator[Action, None, None]


class ExpertFailureError(RuntimeError):
    """A scripted skill could not reach a waypoint or lost its object; ``str()`` is the reason."""


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Wrap angles to [-pi, pi) exactly as CALVIN's ``rel_actions`` do (spec 1.6)."""
    return (np.asarray(angle, dtype=np.float64) + np.pi) % (2 * np.pi) - np.pi


def quat_to_matrix(quat: Any) -> np.ndarray:
    """Rotation matrix (3, 3) of a pybullet quaternion (x, y, z, w)."""
    x, y, z, w = (float(v) for v in quat)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def down_euler(yaw: float) -> np.ndarray:
    """Euler angles (3,) of a TCP pointing down with the given yaw (fingers close along world (sin, -cos))."""
    return np.array([DOWN_ROLL, 0.0, float(wrap_angle(yaw))])


def tilted_euler(yaw: float, tilt: float) -> np.ndarray:
    """Euler (3,) of the down-pointing TCP with ``yaw``, then tilted by ``tilt`` about world x.

    A positive tilt swings the fingertips toward +y (into the cabinet / drawer front) and the hand back toward
    the robot, which keeps the hand clear of the desk edge and the slanted door.
    """
    c, s = np.cos(tilt), np.sin(tilt)
    rx_tilt = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    cy, sy = np.cos(yaw), np.sin(yaw)
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    rx_pi = np.diag([1.0, -1.0, -1.0])
    r = rx_tilt @ rz @ rx_pi
    pitch = -np.arcsin(np.clip(r[2, 0], -1, 1))
    return np.array([np.arctan2(r[2, 1], r[2, 2]), pitch, np.arctan2(r[1, 0], r[0, 0])])


def servo_action(
    tcp_pos: np.ndarray,
    tcp_euler: np.ndarray,
    goal_pos: np.ndarray,
    goal_euler: np.ndarray,
    gripper: float,
    max_step: float,
    max_rot: float = 0.04,
    gain: float = 0.6,
) -> Action:
    """One relative action (7,) moving the measured TCP toward ``goal`` (proportional, speed-capped).

    Args:
        tcp_pos: measured TCP position (3,).
        tcp_euler: measured TCP euler (3,); deltas are wrapped so the roll flip near +-pi is harmless.
        goal_pos: waypoint position (3,).
        goal_euler: waypoint euler (3,).
        gripper: +1 open / -1 close.
        max_step: cap on the commanded translation per step (m, <= 0.02).
        max_rot: cap on the commanded rotation per step per axis (rad, <= 0.05).
        gain: fraction of the remaining error commanded per step; < 1 damps the overshoot that the sim's
            integrating target pose (spec 3.5) would otherwise cause.

    Returns:
        (7,) action in CALVIN's normalised relative space.
    """
    dpos = gain * (np.asarray(goal_pos) - np.asarray(tcp_pos))
    norm = float(np.linalg.norm(dpos))
    if norm > max_step:
        dpos *= max_step / norm
    deul = np.clip(gain * wrap_angle(np.asarray(goal_euler) - np.asarray(tcp_euler)), -max_rot, max_rot)
    action = np.concatenate([np.clip(dpos / POS_SCALE, -1, 1), np.clip(deul / ROT_SCALE, -1, 1), [gripper]])
    return action.astype(np.float64)


@dataclass
class Motion:
    """Speed and randomisation settings of one expert run (drawn once per run from ``np_random``)."""

    speed: float  # m per step on free-space moves
    slow_speed: float  # m per step near contact
    pos_tol: float = 0.006
    rot_tol: float = 0.06


class SkillContext:
    """Closed-loop access to the sim for the skills: measured TCP, object poses, action helpers."""

    def __init__(self, sim: CalvinSimulation, np_random: np.random.Generator, motion: Motion) -> None:
        self.sim = sim
        self.rng = np_random
        self.motion = motion
        info = sim.get_info()
        self.robot_uid: int = int(info["robot_info"]["uid"])
        table = info["scene_info"]["fixed_objects"]["table"]
        self.table_uid: int = int(table["uid"])
        self.links: dict[str, int] = {name: int(idx) for name, idx in table["links"].items()}
        self.block_uids: dict[str, int] = {
            name: int(obj["uid"]) for name, obj in info["scene_info"]["movable_objects"].items()
        }
        self.gripper = float(GRIPPER_OPEN if sim.robot_obs()[14] > 0 else GRIPPER_CLOSE)

    # ---------------------------------------------------------------- state
    def tcp(self) -> tuple[np.ndarray, np.ndarray]:
        """The TCP's position (3,) and euler angles (3,) now.

        Privileged: recomputed from the joints, not ``robot_obs[0:6]``, which reports the pose one physics
        sub-step late as CALVIN does (docs/calvin.md 3.7); the controller steers by the true pose.
        """
        position, orientation = self.sim.robot.tcp_pose(current=True)
        return np.array(position), np.array(self.sim.client.getEulerFromQuaternion(orientation))

    def gripper_width(self) -> float:
        return float(self.sim.robot_obs()[6])

    def block_pose(self, block: str) -> tuple[np.ndarray, np.ndarray]:
        """Block centre (3,) and rotation matrix (3, 3) (columns = the block's local axes in world)."""
        pos, orn = self.sim.client.getBasePositionAndOrientation(self.block_uids[block])
        return np.asarray(pos, dtype=np.float64), quat_to_matrix(orn)

    def block_contacts(self, block: str) -> set[tuple[int, int]]:
        """(body uid, link index) pairs touching ``block`` (pybullet contact layout c[2], c[4])."""
        return {(c[2], c[4]) for c in self.sim.client.getContactPoints(bodyA=self.block_uids[block])}

    def robot_holds(self, block: str) -> bool:
        return any(uid == self.robot_uid for uid, _ in self.block_contacts(block))

    def joint_state(self, link: str) -> float:
        return float(self.sim.client.getJointState(self.table_uid, self.links[link])[0])

    def link_aabb(self, link: str) -> np.ndarray:
        """Axis-aligned box (2, 3) of a table link in world coordinates."""
        return np.asarray(self.sim.client.getAABB(self.table_uid, self.links[link]), dtype=np.float64)

    # --------------------------------------------------------------- skills
    def servo(
        self,
        pos: np.ndarray,
        euler: np.ndarray,
        *,
        speed: float | None = None,
        tol: float | None = None,
        rot_tol: float | None = None,
        max_steps: int = 80,
        what: str = "waypoint",
        allow_timeout: bool = False,
    ) -> Skill:
        """Move the TCP to (pos, euler) keeping the current gripper command; yields one action per step."""
        speed = self.motion.speed if speed is None else speed
        tol = self.motion.pos_tol if tol is None else tol
        rot_tol = self.motion.rot_tol if rot_tol is None else rot_tol
        for _ in range(max_steps):
            tcp_pos, tcp_euler = self.tcp()
            pos_err = float(np.linalg.norm(np.asarray(pos) - tcp_pos))
            rot_err = float(np.abs(wrap_angle(np.asarray(euler) - tcp_euler)).max())
            if pos_err < tol and rot_err < rot_tol:
                return
            yield servo_action(tcp_pos, tcp_euler, pos, euler, self.gripper, speed)
        if not allow_timeout:
            raise ExpertFailureError(
                f"could not reach {what} {np.round(pos, 3).tolist()} in {max_steps} steps"
            )

    def transit(
        self, pos: np.ndarray, euler: np.ndarray, front_y: float = -0.12, **servo_kwargs: Any
    ) -> Skill:
        """Free-space move that keeps clear of the cabinet front (door handle, switch): a move that crosses
        more than 8 cm of x with an end closer to the cabinet than ``front_y`` goes back, across, then in."""
        tcp, tcp_euler = self.tcp()
        if abs(pos[0] - tcp[0]) > 0.08 and max(tcp[1], pos[1]) > front_y:
            # Via points keep the current orientation (a tilted wrist close to the robot base is hard to
            # reach) and are pass-through points: coming within 3 cm, or 40 steps, is enough.
            z = max(tcp[2], pos[2])
            if tcp[1] > front_y:
                yield from self.servo(np.array([tcp[0], front_y, z]), tcp_euler, tol=0.03, rot_tol=0.3,
                                      max_steps=40, what="back off", allow_timeout=True)  # fmt: skip
            yield from self.servo(np.array([pos[0], front_y, z]), tcp_euler, tol=0.03, rot_tol=0.3,
                                  max_steps=40, what="across", allow_timeout=True)  # fmt: skip
        yield from self.servo(pos, euler, **servo_kwargs)

    def hold(self, gripper: float, steps: int) -> Skill:
        """Keep the pose (zero motion) for ``steps`` steps while commanding ``gripper``."""
        self.gripper = gripper
        for _ in range(steps):
            yield np.array([0, 0, 0, 0, 0, 0, gripper], dtype=np.float64)

    def set_gripper(self, gripper: float, max_steps: int = 14) -> Skill:
        """Command the gripper and wait until the fingers stop moving (spec 3.5: ~6-8 steps)."""
        self.gripper = gripper
        previous = self.gripper_width()
        for step in range(max_steps):
            yield np.array([0, 0, 0, 0, 0, 0, gripper], dtype=np.float64)
            width = self.gripper_width()
            if step >= 3 and abs(width - previous) < 5e-4:
                return
            previous = width

    def jitter(self, scale: float, dims: int = 3) -> np.ndarray:
        """Uniform waypoint noise in [-scale, scale] (demonstration variety)."""
        return self.rng.uniform(-scale, scale, size=dims)


def ray_hits(ctx: SkillContext, starts: np.ndarray, ends: np.ndarray, link: str | None = None) -> np.ndarray:
    """Hit points (N, 3) of rays against the table (NaN where missed or hitting another link)."""
    results = ctx.sim.client.rayTestBatch(starts.tolist(), ends.tolist())
    hits = np.full((len(results), 3), np.nan)
    for i, res in enumerate(results):
        if res[0] == ctx.table_uid and (link is None or res[1] == ctx.links[link]):
            hits[i] = res[3]
    return hits
