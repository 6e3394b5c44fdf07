"""SubgoalVLA's data contract, in one place: batch keys, the state-history / subgoal-trace window and the
metadata a dataset carries about them.

Every other part (policy, converters, envs, visualisation, tests) imports its keys and window facts from here;
nothing here imports another part of the project, torch or LeRobot (numpy only), so the light commands and env
workers stay light.

- :mod:`.keys`: the batch keys (LeRobot's own, checked against its constants, plus SubgoalVLA's two columns).
- :mod:`.window`: :class:`~.window.TraceWindow`, the definition of ``observation.state_history`` and
  ``observation.subgoal_trace`` as windows over an episode's ``observation.state``; how it scales with fps.
- :mod:`.metadata`: :class:`~.metadata.ProprioMetadata`, the window, the wrapping angles and the extra
  instructions, stored inside the trace feature's ``info`` in ``meta/info.json`` (where LeRobot reads it
  without a warning) and read back by the policy when it is built for training.
- :mod:`.calvin`: CALVIN's layout of the contract (camera keys, its angle settings), the one CALVIN file here.
"""
