"""Franka Panda controlled by inverse kinematics to a TCP pose, as CALVIN's ``Robot`` (docs/calvin.md section
3.5).

Two URDFs, one behaviour:

* ``calvin_A..D``: CALVIN's ``franka_panda/panda_longer_finger.urdf`` from the user's calvin_env directory:
  TCP = link 15 ``tcp`` (hand + 0.14 m along the hand z axis), gripper camera = link 14, fingers = joints 9,
  11.
* ``procedural``: pybullet's bundled ``franka_panda/panda.urdf`` (ships inside the pybullet wheel). Its
  fingers are shorter than CALVIN's, so the TCP is its ``panda_grasptarget`` link 11 = hand + 0.105 m along z,
  the point between the finger tips; the gripper camera has no link there and is placed at CALVIN's offset
  from the hand (hand + (-0.1, 0, 0), rpy (1.3, 0, -1.57)). Fingers = joints 9, 10. The finger contact
  parameters of CALVIN's URDF (lateral friction 1, spinning 0.1, stiffness 30000, damping 1000, friction
  anchor) are applied by code. Its visual meshes (~100k triangles) are replaced by its own collision meshes
  (~3.5k): TinyRenderer's cost grows with the triangle count, and this makes the static camera about 15 ms
  (~30 %) cheaper per frame (``benchmarks/env_benchmark.py``); the arm looks faceted, which no CALVIN data
  depends on.

Arm joints 0-6 and the observation layout (robot_obs, spec 1.4) are the same for both.

Action semantics (spec 1.6, 3.5):

* ``relative`` (default): ``a[:6]`` is clipped to [-1, 1]; the stored *target* pose (reset to the measured TCP
  pose at every reset, never re-synced afterwards, so saturated commands wind up exactly as in CALVIN) gets
  ``a[0:3] * 0.02`` m and ``a[3:6] * 0.05`` rad added; the euler target is converted to a quaternion and
  solved by IK.
* ``absolute``: ``a[0:3]`` TCP position (m), ``a[3:6]`` TCP euler (rad); the target is set to it.
* Gripper ``a[6]``: CALVIN asserts exactly +-1; like the calvin_agent wrapper we binarise ``> 0 -> +1
  (open)``, else ``-1 (close)``. Non-finite values or a shape other than (7,) raise ``ValueError``.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import pybullet
import pybullet_data
from pybullet_utils.bullet_client import BulletClient

ActionMode = Literal["relative", "absolute"]

#: Default arm pose of every CALVIN scene config (spec 3.5).
DEFAULT_ARM_POSE = (-1.21779206, 1.03987646, 2.11978261, -2.34205014, -0.87015947, 1.64119353, 0.55344866)
ROBOT_BASE_POSITION = (-0.34, -0.46, 0.24)
ARM_JOINTS = (0, 1, 2, 3, 4, 5, 6)
ARM_LOWER = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
ARM_UPPER = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
MAX_JOINT_FORCE = 200.0
MAX_JOINT_VELOCITY = 2.0
GRIPPER_FORCE = 200.0
GRIPPER_OPEN = 0.04
MAX_REL_POS = 0.02  # m per step at |a| = 1
MAX_REL_ORN = 0.05  # rad per step at |a| = 1
HAND_LINK = 8
CAMERA_FROM_HAND = ((-0.1, 0.0, 0.0), (1.3, 0.0, -1.57))  # gripper_cam joint of panda_longer_finger.urdf


@dataclass(frozen=True)
class RobotSpec:
    """Which URDF and which links/joints play the CALVIN roles.

    Attributes:
        urdf: Absolute path of the robot URDF.
        tcp_link: Link whose pose is the TCP (IK target, robot_obs[0:6]).
        finger_joints: The two prismatic finger joints (their sum is the opening width).
        camera_link: Link carrying the gripper camera, or ``None`` to place the camera at
            :data:`CAMERA_FROM_HAND` relative to the hand link.
        set_finger_contacts: Apply CALVIN's finger contact parameters by code (the URDF lacks them).
        low_poly_visuals: Render the URDF's collision meshes instead of its visual meshes (pybullet's
            bundled Panda only: its ``meshes/visual`` and ``meshes/collision`` folders).
    """

    urdf: Path
    tcp_link: int
    finger_joints: tuple[int, int]
    camera_link: int | None
    set_finger_contacts: bool
    low_poly_visuals: bool = False


def procedural_robot_spec() -> RobotSpec:
    """pybullet's bundled Panda: TCP = ``panda_grasptarget`` (hand + 0.105 m), fingers 9 and 10."""
    urdf = Path(pybullet_data.getDataPath()) / "franka_panda" / "panda.urdf"
    return RobotSpec(urdf, 11, (9, 10), None, set_finger_contacts=True, low_poly_visuals=True)


def calvin_robot_spec(data_dir: Path) -> RobotSpec:
    """CALVIN's ``panda_longer_finger.urdf``: TCP link 15, gripper camera link 14, fingers 9 and 11 (spec
    3.5)."""
    return RobotSpec(data_dir / "franka_panda" / "panda_longer_finger.urdf", 15, (9, 11), 14, False)


def _low_poly_urdf(urdf: Path) -> str:
    """The URDF text with every mesh taken from ``meshes/collision`` by absolute path (see the module
    docstring)."""
    collision_dir = (urdf.parent / "meshes" / "collision").as_posix() + "/"
    text = urdf.read_text()
    for prefix in ("package://meshes/visual/", "package://meshes/collision/"):
        text = text.replace(prefix, collision_dir)
    if "package://" in text:
        raise ValueError(f"{urdf}: unexpected mesh paths; cannot build the low-poly variant")
    return text


def validate_action(action: np.ndarray | list[float]) -> np.ndarray:
    """Return ``action`` as a float64 copy of shape (7,), or raise ``ValueError`` naming the problem."""
    arr = np.asarray(action, dtype=np.float64)
    if arr.shape != (7,):
        raise ValueError(f"action must have shape (7,) (pos 3, euler 3, gripper 1), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"action must be finite, got {arr.tolist()}")
    return arr.copy()


class PandaRobot:
    """The Panda of one simulation: loading, reset from robot_obs, IK control, robot_obs and robot_info.

    Args:
        client: The simulation's own BulletClient.
        spec: URDF and link roles (:func:`procedural_robot_spec` or :func:`calvin_robot_spec`).
        action_mode: ``"relative"`` (CALVIN rel_actions) or ``"absolute"`` (TCP pose).
    """

    def __init__(self, client: BulletClient, spec: RobotSpec, action_mode: ActionMode = "relative") -> None:
        if action_mode not in ("relative", "absolute"):
            raise ValueError(f"action_mode must be 'relative' or 'absolute', got {action_mode!r}")
        self.client = client
        self.spec = spec
        self.action_mode = action_mode
        self.uid = -1
        self.gripper_action = 1  # CALVIN initialises it to open and keeps it across resets (spec 3.8)
        self.target_pos = np.zeros(3)
        self.target_orn = np.zeros(3)
        self._rest_pose: list[float] = []

    def load(self) -> None:
        """Load the URDF (body uid 0 in a fresh world), the visual base cylinder and the finger gear (spec
        3.1)."""
        c = self.client
        if self.spec.low_poly_visuals:
            with tempfile.TemporaryDirectory(prefix="subgoalvla_panda_") as tmp:
                urdf = Path(tmp) / "panda_low_poly.urdf"
                urdf.write_text(_low_poly_urdf(self.spec.urdf))
                self.uid = c.loadURDF(str(urdf), ROBOT_BASE_POSITION, (0, 0, 0, 1), useFixedBase=True)
        else:
            self.uid = c.loadURDF(str(self.spec.urdf), ROBOT_BASE_POSITION, (0, 0, 0, 1), useFixedBase=True)
        base_x, base_y, base_z = ROBOT_BASE_POSITION
        cylinder = c.createVisualShape(
            pybullet.GEOM_CYLINDER,
            radius=0.13,
            length=base_z,
            rgbaColor=(1, 1, 1, 1),
            visualFramePosition=(base_x - 0.05, base_y, base_z / 2),
        )
        c.createMultiBody(baseVisualShapeIndex=cylinder)
        left, right = self.spec.finger_joints
        gear = c.createConstraint(
            self.uid, left, self.uid, right, pybullet.JOINT_GEAR, (1, 0, 0), (0, 0, 0), (0, 0, 0)
        )
        c.changeConstraint(gear, gearRatio=-1, erp=0.1, maxForce=50)
        if self.spec.set_finger_contacts:
            for joint in self.spec.finger_joints:
                c.changeDynamics(
                    self.uid,
                    joint,
                    lateralFriction=1.0,
                    spinningFriction=0.1,
                    contactStiffness=30000.0,
                    contactDamping=1000.0,
                    frictionAnchor=1,
                )
        num_dof = c.computeDofCount(self.uid)
        if num_dof != 9:
            raise ValueError(f"{self.spec.urdf}: expected a Panda with 9 movable joints, found {num_dof}")
        self._rest_pose = [*DEFAULT_ARM_POSE, GRIPPER_OPEN, GRIPPER_OPEN]

    # ------------------------------------------------------------------ reset / observation
    def reset(self, robot_obs: np.ndarray | None = None) -> None:
        """Set joints from ``robot_obs[7:14]`` and fingers from ``robot_obs[6] / 2`` (spec 3.8 step 2).

        ``robot_obs[0:6]`` and ``robot_obs[14]`` are ignored, as in CALVIN: the stored gripper command keeps
        its value from before the reset. Without ``robot_obs`` the default arm pose with open fingers is used.
        """
        if robot_obs is None:
            arm, finger = np.array(DEFAULT_ARM_POSE), GRIPPER_OPEN
        else:
            arm, finger = robot_obs[7:14], float(robot_obs[6]) / 2
        c = self.client
        for joint, value in zip(ARM_JOINTS, arm, strict=True):
            c.resetJointState(self.uid, joint, float(value))
        self._command_arm(arm)
        for joint in self.spec.finger_joints:
            c.resetJointState(self.uid, joint, finger)
            c.setJointMotorControl2(
                self.uid,
                joint,
                pybullet.POSITION_CONTROL,
                targetPosition=finger,
                force=GRIPPER_FORCE,
                maxVelocity=1,
            )
        pos, orn = self.tcp_pose(current=True)
        self.target_pos = np.array(pos)
        self.target_orn = np.array(c.getEulerFromQuaternion(orn))

    def tcp_pose(
        self, current: bool = False
    ) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """World TCP position (m) and quaternion (x, y, z, w).

        By default the pose CALVIN reports: ``getLinkState`` without ``computeForwardKinematics``, the link
        transform pybullet cached at the start of the last physics sub-step, 1/240 s behind the joints
        (about 1 mm while the arm moves; spec 3.5). ``current=True`` recomputes it from the joint positions,
        as the control needs (the reset's target pose; after ``resetJointState`` both agree).
        """
        state = self.client.getLinkState(self.uid, self.spec.tcp_link, computeForwardKinematics=current)
        return state[0], state[1]

    def gripper_width(self) -> float:
        """Sum of the two finger joint positions (m), robot_obs[6]."""
        left, right = self.client.getJointStates(self.uid, list(self.spec.finger_joints))
        return float(left[0] + right[0])

    def arm_joint_states(self) -> list[float]:
        """The seven arm joint positions (rad), robot_obs[7:14]."""
        return [s[0] for s in self.client.getJointStates(self.uid, list(ARM_JOINTS))]

    def observation(self) -> np.ndarray:
        """robot_obs (15,) float64: TCP pos, TCP euler, gripper width, 7 joints, last gripper action (spec
        1.4)."""
        pos, orn = self.tcp_pose()
        euler = self.client.getEulerFromQuaternion(orn)
        return np.array(
            [*pos, *euler, self.gripper_width(), *self.arm_joint_states(), self.gripper_action],
            dtype=np.float64,
        )

    def info(self) -> dict:
        """CALVIN's ``robot_info`` (spec 2.1); contacts of the last physics sub-step."""
        pos, orn = self.tcp_pose()
        return {
            "tcp_pos": pos,
            "tcp_orn": self.client.getEulerFromQuaternion(orn),
            "gripper_opening_width": self.gripper_width(),
            "arm_joint_states": self.arm_joint_states(),
            "gripper_action": self.gripper_action,
            "uid": self.uid,
            "contacts": self.client.getContactPoints(bodyA=self.uid),
        }

    def camera_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """World position and 3x3 rotation of the gripper camera frame (link 14 or hand + CALVIN's offset),
        from the transform cached at the last physics sub-step, as CALVIN poses it."""
        c = self.client
        if self.spec.camera_link is not None:
            # The cached transform, as CALVIN's gripper camera reads it (see tcp_pose).
            state = c.getLinkState(self.uid, self.spec.camera_link)
            pos, orn = state[0], state[1]
        else:
            hand = c.getLinkState(self.uid, HAND_LINK)
            offset_pos, offset_rpy = CAMERA_FROM_HAND
            pos, orn = c.multiplyTransforms(
                hand[4], hand[5], offset_pos, c.getQuaternionFromEuler(offset_rpy)
            )
        return np.array(pos), np.array(c.getMatrixFromQuaternion(orn)).reshape(3, 3)

    # ------------------------------------------------------------------ control
    def apply_action(self, action: np.ndarray) -> None:
        """Update the target pose from a validated (7,) action, solve IK and set motor targets (spec 3.5)."""
        action = validate_action(action)
        if self.action_mode == "relative":
            rel = np.clip(action[:6], -1.0, 1.0)
            self.target_pos = self.target_pos + rel[0:3] * MAX_REL_POS
            self.target_orn = self.target_orn + rel[3:6] * MAX_REL_ORN
        else:
            self.target_pos = action[0:3].copy()
            self.target_orn = action[3:6].copy()
        self.gripper_action = 1 if action[6] > 0 else -1
        self._move_arm(self.target_pos, self.client.getQuaternionFromEuler(self.target_orn.tolist()))
        self._move_gripper(self.gripper_action)

    def _move_arm(self, pos: np.ndarray, quat: tuple[float, ...]) -> None:
        c = self.client
        joints = c.calculateInverseKinematics(
            self.uid,
            self.spec.tcp_link,
            pos.tolist(),
            quat,
            lowerLimits=[-7.0] * 9,
            upperLimits=[7.0] * 9,
            jointRanges=[7.0] * 9,
            restPoses=self._rest_pose,
            maxNumIterations=20,
            residualThreshold=1e-4,
        )
        self._command_arm(np.clip(np.asarray(joints[:7]), ARM_LOWER, ARM_UPPER))

    def _command_arm(self, targets: np.ndarray | list[float]) -> None:
        """Position-control the 7 arm joints to ``targets`` (force 200, max 2 rad/s: spec 3.5)."""
        for joint, value in zip(ARM_JOINTS, targets, strict=True):
            self.client.setJointMotorControl2(
                self.uid,
                joint,
                pybullet.POSITION_CONTROL,
                targetPosition=float(value),
                force=MAX_JOINT_FORCE,
                maxVelocity=MAX_JOINT_VELOCITY,
            )

    def _move_gripper(self, gripper_action: int) -> None:
        """+1 opens (target 0.04, force 2), -1 closes (target 0, force 200); maxVelocity 1 (spec 3.5)."""
        target, force = (GRIPPER_OPEN, GRIPPER_FORCE / 100) if gripper_action == 1 else (0.0, GRIPPER_FORCE)
        for joint in self.spec.finger_joints:
            self.client.setJointMotorControl2(
                self.uid, joint, pybullet.POSITION_CONTROL, targetPosition=target, force=force, maxVelocity=1
            )
