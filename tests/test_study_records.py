"""The study's results file: records replace their earlier versions, and a shorter evaluation is continued."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

STUDY = Path(__file__).resolve().parents[1] / "benchmarks" / "study"


@pytest.fixture
def common(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.syspath_prepend(str(STUDY))
    import common as study_common

    yield study_common
    sys.modules.pop("common", None)


def _record(task: str, successes: int, episodes: int, samples: int = 80000, **extra) -> dict:
    return {
        "method": "subgoalvla",
        "setting": "multi_task",
        "task": task,
        "seed": 0,
        "episodes": episodes,
        "successes": successes,
        "train_samples": samples,
        **extra,
    }


def _write_eval(eval_dir: Path, successes: list[bool]) -> None:
    eval_dir.mkdir(parents=True)
    info = {"per_task": [{"metrics": {"successes": successes}}], "overall": {"eval_s": 2.0 * len(successes)}}
    (eval_dir / "eval_info.json").write_text(json.dumps(info))


def test_a_stored_record_replaces_its_earlier_version_only(common, tmp_path: Path) -> None:
    path = tmp_path / "results.json"
    common.store_records([_record("open_drawer", 5, 10), _record("open_drawer", 9, 10, samples=96000)], path)
    common.store_records([_record("open_drawer", 12, 20)], path)
    stored = {(r["train_samples"], r["episodes"]): r["successes"] for r in common.load_records(path)}
    assert stored == {(96000, 10): 9, (80000, 20): 12}


def test_a_shorter_evaluation_continues_from_the_next_seed(common, tmp_path, monkeypatch) -> None:
    demo = tmp_path / "demo"  # a run imported from a demo folder: its checkpoint and first 10 episodes
    (demo / "train" / "checkpoints" / "last" / "pretrained_model").mkdir(parents=True)
    _write_eval(demo / "eval" / "open_drawer", [True] * 6 + [False] * 4)
    results = tmp_path / "results.json"
    common.store_records([_record("open_drawer", 6, 10, source=str(demo), train_seconds=60.0)], results)
    commands = []

    def fake_run(command, log_path):
        commands.append(command)
        flags = dict(arg[2:].split("=", 1) for arg in command[1:])
        _write_eval(Path(flags["output_dir"]), [True] * int(flags["eval.n_episodes"]))
        return 1.0

    monkeypatch.setattr(common, "run", fake_run)
    method = common.Method("subgoalvla", ("--policy.type=subgoalvla",))
    data = common.DataSpec("fixtures", ("open_drawer",), 240)
    spec = common.RunSpec(method, "multi_task", data, ("open_drawer",), 0, 2500, 20)
    (record,) = common.execute(spec, tmp_path / "work", results)
    assert len(commands) == 1 and "--seed=1010" in commands[0] and "--eval.n_episodes=10" in commands[0]
    assert (record["episodes"], record["successes"], record["train_seconds"]) == (20, 16, 60.0)
    assert common.load_records(results) == [record]
    assert common.execute(spec, tmp_path / "work", results) == []  # done: nothing is evaluated again
    assert len(commands) == 1
