"""CALVIN as a LeRobot environment.

Sub-packages, in dependency order (each imports only those above it):

- ``sim/``: the pybullet simulator (scene, robot, cameras, CALVIN's asset files);
- ``oracle/``: CALVIN's task-success predicates;
- ``evaluation/``: the LH-MTLC chains, their start scenes, per-chain results and the LH-1..5 report;
- ``expert/``: the scripted expert and the per-task start states it can solve from.

On top: ``env.py`` (the gymnasium env), ``vector.py`` (vector envs for ``lerobot-eval``) and ``configs.py``
(``CalvinEnvConfig``, the only module that imports LeRobot's env machinery). ``protocol.py`` holds the
benchmark's fixed numbers. Importing this package registers the gymnasium id ``lerobot_subgoalvla/Calvin-v0``
and nothing heavier (gymnasium registration is lazy: the env module is imported by ``gymnasium.make``).
"""

import gymnasium as gym

from lerobot_subgoalvla.envs.calvin.protocol import GYM_ID

if GYM_ID not in gym.registry:
    # No TimeLimit wrapper: the env ends its own episodes (per-subtask budgets) and sets _max_episode_steps.
    gym.register(GYM_ID, entry_point="lerobot_subgoalvla.envs.calvin.env:CalvinEnv")
