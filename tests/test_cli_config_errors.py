"""A bad --policy.* or --env.* value reaches users of LeRobot's CLIs as our one-line message, exit 1."""

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
