"""CALVIN's layout of the data contract: its two cameras and its wrapping angles (one file per robot's key
mapping; the policy never imports it, it learns these facts from the dataset or the env).

- Cameras: ``observation.images.static`` (CALVIN's ``rgb_static``, 200 px) and
  ``observation.images.gripper`` (``rgb_gripper``, 84 px), in this order in every CALVIN dataset and env, so a
  policy trained on one sees them in the same order in the other.
- Angles: ``robot_obs[3:6]`` is the TCP orientation as XYZ Euler angles in (-pi, pi]. With the gripper
  pointing down the roll sits at +-pi and wraps at the slightest rotation, so the converter records these dims
  with the home orientation (pi, 0, 0); the policy then sees ``wrap(angle - home)``, continuous wherever the
  arm goes.
"""

from __future__ import annotations

import math

from lerobot_subgoalvla.contract.keys import IMAGES_PREFIX

STATIC_CAMERA = "static"
GRIPPER_CAMERA = "gripper"
STATIC_CAMERA_KEY = IMAGES_PREFIX + STATIC_CAMERA
GRIPPER_CAMERA_KEY = IMAGES_PREFIX + GRIPPER_CAMERA
#: camera keys in the order CALVIN's datasets and env declare them.
CAMERA_KEYS = (STATIC_CAMERA_KEY, GRIPPER_CAMERA_KEY)
#: the converter's column of CALVIN frame ids (traceability back to the native files).
FRAME_INDEX_KEY = "calvin_frame_index"
ROBOT_TYPE = "franka_panda"
#: ``robot_obs`` indices of the TCP Euler angles and the orientation they are measured from.
ANGLE_DIMS = (3, 4, 5)
ANGLE_HOME = (math.pi, 0.0, 0.0)
