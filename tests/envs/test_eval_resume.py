"""Sharded LH-MTLC evaluation: a stopped run continues with --env.resume=true to the uninterrupted result."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from eval_shard import evaluate

from lerobot_subgoalvla.config_error import ConfigError
from lerobot_subgoalvla.envs.calvin.configs import CalvinEnvConfig
from lerobot_subgoalvla.envs.calvin.evaluation.report import main as report_main
from lerobot_subgoalvla.envs.calvin.evaluation.results import read_episode_results

pytest.importorskip("pybullet")


def _report(results: Path, out: Path) -> dict:
    assert report_main([str(results), "--output-dir", str(out)]) == 0
    return json.loads((out / "results.json").read_text())


@pytest.mark.slow  # about 35 s: a subprocess importing LeRobot, then three evaluations
def test_sigkill_mid_evaluation_then_resume_gives_the_uninterrupted_report(tmp_path: Path) -> None:
    """Chains 0..7 in two shards ([0, 5) killed after 2 chains and resumed, then [5, 8) into the same file):
    every chain once, and records and LH report equal those of one uninterrupted run over [0, 8)."""
    killed = tmp_path / "killed.jsonl"
    script = Path(__file__).with_name("eval_shard.py")
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(sys.path),
        "HF_HUB_OFFLINE": "1",
        "OMP_NUM_THREADS": "1",
    }
    process = subprocess.Popen(
        [sys.executable, str(script), str(killed), "0", "5", "new", "0.05"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    deadline = time.monotonic() + 300
    while process.poll() is None and time.monotonic() < deadline:
        if killed.is_file() and killed.read_text().count("\n") >= 2:
            break
        time.sleep(0.01)
    process.send_signal(signal.SIGKILL)
    assert process.wait() == -signal.SIGKILL, "the evaluation ended before it could be killed"
    assert 2 <= len(read_episode_results(killed)) < 5
    with pytest.raises(
        ConfigError, match="already holds .* chain\\(s\\) of \\[0, 5\\); pass --env.resume=true"
    ):
        CalvinEnvConfig(chain_start=0, chain_stop=5, results_path=str(killed))  # a plain rerun is refused
    done_before = {r.chain_id for r in read_episode_results(killed)}
    info = evaluate(killed, 0, 5, resume=True)
    assert {e["task_id"] for e in info["per_task"]} == set(range(5)) - done_before  # only the missing ones
    evaluate(killed, 5, 8)  # the second shard appends to the same file
    reference = tmp_path / "reference.jsonl"
    evaluate(reference, 0, 8)
    got, want = read_episode_results(killed), read_episode_results(reference)
    assert sorted(got, key=lambda r: r.chain_id) == want
    assert (
        len({r.num_completed for r in want}) > 1
    )  # the chains' results differ: the comparison means something
    assert _report(killed, tmp_path / "r1") == _report(reference, tmp_path / "r2")
    with pytest.raises(ConfigError, match="already holds every chain of \\[0, 5\\); nothing to evaluate"):
        CalvinEnvConfig(chain_start=0, chain_stop=5, results_path=str(killed), resume=True)


def test_an_incomplete_last_line_is_redone_on_resume_and_named_by_the_report(tmp_path: Path, caplog) -> None:
    results = tmp_path / "results.jsonl"
    evaluate(results, 0, 2)
    whole = results.read_text()
    results.write_text(whole + whole.splitlines()[0][:25])  # a third record cut mid-line (power loss)
    with pytest.raises(SystemExit):
        report_main([str(results), "--output-dir", str(tmp_path / "r")])
    (message,) = [r.getMessage() for r in caplog.records if r.levelname == "ERROR"]
    assert ":3: incomplete last line" in message and "--env.resume=true" in message
    evaluate(results, 0, 3, resume=True)
    assert results.read_text().startswith(whole) and [r.chain_id for r in read_episode_results(results)] == [
        0,
        1,
        2,
    ]
