"""LeRobot's own CLIs on our plugin: bad values reach the user as one line; every flag has a help."""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest

ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}


def _run(command: list[str]) -> subprocess.CompletedProcess:
    if shutil.which(command[0]) is None:
        pytest.skip(f"{command[0]} is not installed")
    return subprocess.run(command, capture_output=True, text=True, env=ENV, timeout=300)


def test_bad_policy_value_names_the_flag_and_the_allowed_values(tmp_path) -> None:
    result = _run(["lerobot-train", "--policy.type=subgoalvla", "--policy.preset=huge",
                   "--dataset.repo_id=local/x", f"--dataset.root={tmp_path}"])  # fmt: skip
    assert result.returncode == 1
    assert "--policy.preset='huge' is not valid; allowed values: tiny, laptop, small, paper" in result.stderr
    assert "Couldn't instantiate" not in result.stderr


def test_bad_env_value_is_one_line_without_a_traceback() -> None:
    result = _run(["lerobot-eval", "--policy.type=subgoalvla", "--env.type=calvin", "--env.scene=foo"])
    assert result.returncode == 1
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("error: --env.scene='foo' is not valid; use one of: procedural, calvin_A")
    assert "ParsingError" not in result.stderr


def test_every_policy_and_env_flag_has_a_one_line_help() -> None:
    import re

    result = _run(["lerobot-train", "--policy.type=subgoalvla", "--env.type=calvin", "--help"])
    lines = result.stdout.splitlines()
    flags, missing = 0, []
    for i, line in enumerate(lines):
        match = re.match(r"^  (--(?:policy|env)\.\S+)", line)
        if not match:
            continue
        flags += 1
        same_line = re.search(r"\S\s{2,}\S", line.strip())
        next_line = i + 1 < len(lines) and re.match(r"^\s{20,}[^\s-]", lines[i + 1])
        if not (same_line or next_line):
            missing.append(match.group(1))
    assert flags > 60 and not missing, f"flags without help: {missing}"
    assert "------" not in result.stdout  # no section banners standing in for help


def test_the_plugin_module_registers_everything_in_a_fresh_interpreter() -> None:
    """What LeRobot's discovery (and a user script) imports: policy, scheduler, processor steps and env."""
    import sys
    import textwrap

    script = textwrap.dedent(
        """
        import sys
        import lerobot_subgoalvla
        assert "torch" not in sys.modules  # the bare package stays light and registers nothing
        import lerobot_subgoalvla.plugin
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.envs.configs import EnvConfig
        from lerobot.optim.schedulers import LRSchedulerConfig
        from lerobot.processor import ProcessorStepRegistry
        assert PreTrainedConfig.get_choice_class("subgoalvla").__name__ == "SubgoalVLAConfig"
        assert EnvConfig.get_choice_class("calvin").__name__ == "CalvinEnvConfig"
        assert LRSchedulerConfig.get_choice_class("subgoalvla_two_stage_cosine")
        for name in ("subgoalvla_tokenizer_processor", "subgoalvla_proprio_normalizer"):
            assert ProcessorStepRegistry.get(name)
        assert "transformers.models.llava" not in sys.modules  # the model loads only when a policy is built
        print("ok")
        """
    )
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=ENV, timeout=300
    )
    assert result.returncode == 0 and result.stdout.strip().endswith("ok"), result.stderr[-2000:]
