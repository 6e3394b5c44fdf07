"""Seeing what the planner plans: subgoal traces rendered as ghost robots over a rollout.

``ghost_robots`` draws a trace of ``robot_obs`` states into the static camera's view (simulator only);
``render_traces`` is the ``subgoalvla-render-traces`` command that rolls a checkpoint out and calls it.
"""
