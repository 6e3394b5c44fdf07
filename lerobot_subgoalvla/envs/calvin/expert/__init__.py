"""The scripted expert: solves every CALVIN task from privileged simulator state, for data generation.

``scripted_expert.ScriptedExpert`` dispatches to the task scripts (``block_scripts``, ``fixture_scripts``),
which move with the motion primitives of ``skills`` inside the scene geometry measured by ``layout``.
``start_states`` samples a valid start state per task (it uses the expert to set up held or stacked blocks).
"""
