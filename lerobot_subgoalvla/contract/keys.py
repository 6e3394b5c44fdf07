"""Batch keys of the data contract.

LeRobot's own keys (state, action, environment state, images) have the values of LeRobot's
``lerobot.utils.constants`` (``tests/test_contract.py`` checks they agree): they are written out here because
importing that module loads torch (``lerobot.utils`` imports its device helpers), and this module must stay
light for the commands and env workers. SubgoalVLA adds two per-frame columns, named here and nowhere else:

- ``observation.state_history`` (h, p): the last h states, oldest first (``window.TraceWindow``).
- ``observation.subgoal_trace`` (M, p): M future states, the planner's target (paper section 4.2).
"""

from __future__ import annotations

OBS_PREFIX = "observation."
STATE_KEY = OBS_PREFIX + "state"
ACTION_KEY = "action"
ENV_STATE_KEY = OBS_PREFIX + "environment_state"
#: a single-camera dataset's image key (Meta-World, PushT); several cameras are ``observation.images.<name>``.
SINGLE_IMAGE_KEY = OBS_PREFIX + "image"
IMAGES_PREFIX = OBS_PREFIX + "images."
STATE_HISTORY_KEY = OBS_PREFIX + "state_history"
SUBGOAL_TRACE_KEY = OBS_PREFIX + "subgoal_trace"
#: the columns SubgoalVLA adds to a dataset (``subgoalvla-add-traces``, ``subgoalvla-convert-calvin``).
TRACE_COLUMNS = (STATE_HISTORY_KEY, SUBGOAL_TRACE_KEY)
#: the instruction of a frame, in a dataset item and in the batch the env gives the policy.
TASK_KEY = "task"
#: LeRobot's padding mask of the action chunk (``<key>_is_pad`` for keys with delta timestamps).
ACTION_IS_PAD_KEY = ACTION_KEY + "_is_pad"
