"""CALVIN's success oracle: which of the 34 tasks an env transition completed (``tasks.TaskOracle``).

Reads only info snapshots (robot and scene state), never the simulator, so the env, the expert's data
generator and the evaluation all judge success with the same predicates.
"""
