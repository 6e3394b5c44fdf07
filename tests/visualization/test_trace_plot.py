"""subgoalvla-plot-traces: usage errors are one line (the plotted rollout itself is tested in Meta-World's
env, tests/metaworld/test_subgoalvla_metaworld.py)."""

from __future__ import annotations

import pytest


def test_an_unknown_env_type_is_one_line(caplog: pytest.LogCaptureFixture) -> None:
    from lerobot_subgoalvla.visualization import trace_plot

    argv = ["--policy-path", "nowhere", "--env-type", "metaword", "--task", "reach-v3", "--output", "x.png"]
    with pytest.raises(SystemExit) as exit_info:
        trace_plot.main(argv)
    assert exit_info.value.code == 1
    assert "--env-type metaword: not a LeRobot env type; choose one of" in caplog.text
    assert "metaworld" in caplog.text.split("choose one of")[1]  # the allowed values are named
