"""Batch keys of the data contract.

LeRobot's own keys (state, action, environment state, images) are LeRobot's constants, re-exported under the
names the project uses; SubgoalVLA adds two per-frame columns, named here and nowhere else:

- ``observation.state_history`` (h, p): the last h states, oldest first (``window.TraceWindow``).
- ``observation.subgoal_trace`` (M, p): M future states, the planner's target (paper section 4.2).
"""

from __future__ import annotations

from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGE, OBS_IMAGES, OBS_PREFIX, OBS_STATE

STATE_KEY = OBS_STATE
ACTION_KEY = ACTION
ENV_STATE_KEY = OBS_ENV_STATE
#: a single-camera dataset's image key (Meta-World, PushT); several cameras are ``observation.images.<name>``.
SINGLE_IMAGE_KEY = OBS_IMAGE
IMAGES_PREFIX = OBS_IMAGES + "."
STATE_HISTORY_KEY = OBS_PREFIX + "state_history"
SUBGOAL_TRACE_KEY = OBS_PREFIX + "subgoal_trace"
#: the columns SubgoalVLA adds to a dataset (``subgoalvla-add-traces``, ``subgoalvla-convert-calvin``).
TRACE_COLUMNS = (STATE_HISTORY_KEY, SUBGOAL_TRACE_KEY)
#: the instruction of a frame, in a dataset item and in the batch the env gives the policy.
TASK_KEY = "task"
#: LeRobot's padding mask of the action chunk (``<key>_is_pad`` for keys with delta timestamps).
ACTION_IS_PAD_KEY = ACTION + "_is_pad"


def camera_name(key: str) -> str:
    """The short name of a camera key: ``observation.images.static`` -> ``static``, ``observation.image`` ->
    ``image``."""
    return key.removeprefix(IMAGES_PREFIX).removeprefix(OBS_PREFIX)
