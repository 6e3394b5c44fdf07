"""Per-episode result records: validation, outcomes, JSON lines, shard merging, lerobot-eval import."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lerobot_subgoalvla.atomic_files import atomic_write
from lerobot_subgoalvla.envs.calvin.evaluation.results import (
    EpisodeResult,
    append_episode_result,
    episode_results_from_eval_info,
    merge_results,
    read_episode_results,
)

TASKS = ("open_drawer", "turn_on_led", "lift_red_block_table", "place_in_drawer", "move_slider_left")


def test_outcomes_and_steps() -> None:
    result = EpisodeResult(4, TASKS, 2, subtask_steps=(30, 41, 360))
    assert result.outcomes == ("success", "success", "failure", "not_attempted", "not_attempted")
    assert result.steps == 431
    assert EpisodeResult(4, TASKS, 5).outcomes == ("success",) * 5
    assert EpisodeResult(4, TASKS, 0).outcomes == ("failure",) + ("not_attempted",) * 4
    assert EpisodeResult(4, TASKS, 0).steps is None


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"num_completed": 6}, "num_completed"),
        ({"num_completed": -1}, "num_completed"),
        ({"num_completed": 2, "subtask_steps": (10, 10)}, "subtask_steps"),
        ({"tasks": ("open_the_fridge",) * 5}, "valid tasks"),
    ],
)
def test_invalid_records(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        EpisodeResult(**{"chain_id": 0, "tasks": TASKS, "num_completed": 1, **kwargs})


def test_jsonl_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "logs" / "results.jsonl"
    records = [EpisodeResult(3, TASKS, 2, (5, 6, 360)), EpisodeResult(1, TASKS, 5, (1, 2, 3, 4, 5))]
    for record in records:
        append_episode_result(path, record)
    assert read_episode_results(path) == records
    line = json.loads(path.read_text().splitlines()[0])
    assert line["outcomes"] == ["success", "success", "failure", "not_attempted", "not_attempted"]
    assert line["steps"] == 371


def test_jsonl_errors_name_the_line(tmp_path: Path) -> None:
    path = tmp_path / "results.jsonl"
    append_episode_result(path, EpisodeResult(0, TASKS, 1))
    with path.open("a") as f:
        f.write('{"chain_id": 1, "tasks": ["open_drawer"], "num_completed": 1, "outcomes": ["failure"]}\n')
    with pytest.raises(ValueError, match=r"results\.jsonl:2"):
        read_episode_results(path)
    with pytest.raises(FileNotFoundError, match="missing"):
        read_episode_results(tmp_path / "missing.jsonl")


def test_merge_sorts_and_rejects_duplicates() -> None:
    a = [EpisodeResult(5, TASKS, 1), EpisodeResult(0, TASKS, 2)]
    b = [EpisodeResult(3, TASKS, 0)]
    assert [r.chain_id for r in merge_results({"a": a, "b": b})] == [0, 3, 5]
    with pytest.raises(ValueError, match=r"chain 5 appears twice \(a and c\)"):
        merge_results({"a": a, "b": b, "c": [EpisodeResult(5, TASKS, 4)]})


def test_eval_info_import() -> None:
    chain_tasks = {0: TASKS, 1: TASKS[::-1]}
    eval_info = {"per_task": [{"task_group": "calvin", "task_id": 1, "metrics": {"sum_rewards": [3.0]}},
                              {"task_group": "calvin", "task_id": 0, "metrics": {"sum_rewards": [0.0]}}],
                 "overall": {"avg_sum_reward": 1.5}}  # fmt: skip
    results = episode_results_from_eval_info(eval_info, chain_tasks)
    assert results == [EpisodeResult(1, TASKS[::-1], 3), EpisodeResult(0, TASKS, 0)]
    # lerobot-eval's avg_sum_reward is CALVIN's average length
    assert sum(r.num_completed for r in results) / len(results) == eval_info["overall"]["avg_sum_reward"]


@pytest.mark.parametrize(
    ("entry", "match"),
    [
        ({"task_id": 9, "metrics": {"sum_rewards": [1.0]}}, "task_id 9"),
        ({"task_id": 0, "metrics": {"sum_rewards": [1.5]}}, "whole number"),
        ({"task_id": 0, "metrics": {"sum_rewards": [1.0, 1.0]}}, "n_episodes=1"),
        ({"task_id": 0, "metrics": {}}, "sum_rewards"),
        ({"task_id": 0, "metrics": {"sum_rewards": [6.0]}}, "num_completed"),
        # what a single-task run (--env.task=open_drawer, task_id 14 = its CALVIN id) writes: not a chain
        ({"task_id": 0, "metrics": {"sum_rewards": [1.0], "successes": [True]}}, "single-task evaluation"),
        # a failed single-task episode (0 completed, no success) looks like a chain but for its group name
        (
            {
                "task_group": "calvin_open_drawer",
                "task_id": 0,
                "metrics": {"sum_rewards": [0.0], "successes": [False]},
            },
            "single-task evaluation, not LH-MTLC chains",
        ),
    ],
)
def test_eval_info_errors(entry: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        episode_results_from_eval_info({"per_task": [entry]}, {0: TASKS})
    with pytest.raises(ValueError, match="per_task"):
        episode_results_from_eval_info({"overall": {}}, {0: TASKS})


def test_atomic_write(tmp_path: Path) -> None:
    target = tmp_path / "deep" / "file.bin"
    atomic_write(target, b"\x00\x01")
    atomic_write(target, "text")
    assert target.read_text() == "text"
    assert target.stat().st_mode & 0o044  # readable by others (mkstemp alone makes 0600 files)
    assert [p.name for p in target.parent.iterdir()] == ["file.bin"]
    other = tmp_path / "other.bin"
    atomic_write(other, lambda handle: handle.write(b"xyz"))  # a writer function
    assert other.read_bytes() == b"xyz"
