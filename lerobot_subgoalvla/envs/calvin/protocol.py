"""The fixed numbers of CALVIN's benchmark protocol, shared by the env, its LeRobot config and the evaluation.

Kept in a module of its own, free of heavy imports, so that ``env.py`` and ``configs.py`` both depend on it
instead of on each other.
"""

from __future__ import annotations

#: The long-horizon multi-task language-control protocol: one episode = one chain of five subtasks.
LH_MTLC = "lh_mtlc"
#: Number of chains of CALVIN's official evaluation (docs/calvin.md 4.1).
NUM_EVAL_CHAINS = 1000
#: Subtasks per evaluation chain (docs/calvin.md 4.1).
CHAIN_LENGTH = 5
#: CALVIN's per-subtask step budget EP_LEN (docs/calvin.md 4.3).
CALVIN_EP_LEN = 360
SCENES: tuple[str, ...] = ("procedural", "calvin_A", "calvin_B", "calvin_C", "calvin_D")
ACTION_MODES: tuple[str, ...] = ("relative", "absolute")
#: Camera renderers: pybullet's CPU TinyRenderer, or OpenGL through the EGL plugin (what CALVIN's data used).
RENDERERS: tuple[str, ...] = ("tiny", "egl")
#: ``gymnasium.make(GYM_ID, task=..., ...)`` builds a ``CalvinEnv`` (registered by ``envs/calvin/__init__``).
GYM_ID = "lerobot_subgoalvla/Calvin-v0"

#: the reset option LeRobot sends at the start of each rollout (``lerobot.envs.utils``; checked by
#: ``tests/envs/test_vector.py``): the env accepts it, the frozen vector sub-envs (``vector.py``) run again.
NEW_ROLLOUT_OPTION = "lerobot_new_rollout"
