"""CALVIN's evaluation protocol: the 1000 LH-MTLC chains, their start scenes, per-chain results and the
report.

``chains`` samples and lists the chains (and is the ``subgoalvla-calvin-chains`` command), ``chain_scene``
turns a chain's symbolic start into simulator state, ``results`` reads and writes the per-chain records, and
``report`` aggregates them into CALVIN's LH-1..5 table (``subgoalvla-calvin-report``). Light: no torch, no
LeRobot.
"""
