"""Meta-World expert demonstrations recorded through LeRobot's own Meta-World env (docs/metaworld.md).

``subgoalvla-generate-metaworld`` (``generate.py``) runs Meta-World's scripted expert policies inside the gym
env that ``lerobot-eval --env.type=metaworld`` builds, and writes the successful episodes as a LeRobotDataset
v3 with the features and task strings of LeRobot's published ``lerobot/metaworld_mt50``. ``tasks.py`` holds
the task sets and name checks, ``record.py`` turns one episode into frames.

Importing this package is light: no torch, LeRobot, MuJoCo or Meta-World until a function needs them.
"""
