"""The study's tables: the spread says what it is, runs of different code eras are never pooled, Meta-World's
one-seed rows show each task's Wilson interval, and --compare names each run's era."""

from __future__ import annotations

import pytest
from helpers.study import study_module


@pytest.fixture
def tables(monkeypatch: pytest.MonkeyPatch):
    yield from study_module(monkeypatch, "tables")


def _run(
    method: str, seed: int, successes: dict[str, int], era: str | None = "b6dfa55", **extra
) -> list[dict]:
    """One run's records: ``successes`` of 20 episodes per task."""
    return [
        {
            "method": method,
            "setting": "multi_task",
            "task": task,
            "seed": seed,
            "episodes": 20,
            "successes": done,
            "train_samples": 80000,
            "train_frames": 16887,
            "code_era": era,
            **extra,
        }
        for task, done in successes.items()
    ]


def _row(lines: list[list[str]], **wanted: str) -> dict[str, str]:
    """The one table row whose cells match ``wanted`` (column name -> cell)."""
    rows = [dict(zip(lines[0], line, strict=True)) for line in lines[1:]]
    (row,) = [r for r in rows if all(r[k] == v for k, v in wanted.items())]
    return row


def test_the_spread_is_the_sample_sd_over_the_seeds_with_their_count_and_range(tables) -> None:
    # seed means 80, 75 and 90 %: mean 81.7, sample sd 7.6 (not half the range, 7.5), range 75.0-90.0
    records = [
        *_run("subgoalvla", 0, {"open_drawer": 16, "close_drawer": 16}),
        *_run("subgoalvla", 1, {"open_drawer": 14, "close_drawer": 16}),
        *_run("subgoalvla", 2, {"open_drawer": 18, "close_drawer": 18}),
        *_run("subgoalvla_t100", 0, {"open_drawer": 6, "close_drawer": 16}),
    ]
    lines = tables.table_lines(records, "multi_task")
    row = _row(lines, method="subgoalvla")
    assert row["mean % (sd, n)"] == "81.7 (sd 7.6, n=3)"
    assert row["seed range"] == "75.0-90.0"
    assert (row["seeds"], row["o_drawer"], row["c_drawer"]) == ("0,1,2", "48/60", "50/60")
    one = _row(lines, method="subgoalvla_t100")
    assert (one["mean % (sd, n)"], one["seed range"]) == ("55.0 (n=1)", "-")
    assert not any("+-" in cell for line in lines for cell in line)


def test_runs_of_different_code_eras_are_rows_of_their_own(tables) -> None:
    records = [
        *_run("subgoalvla", 0, {"open_drawer": 20}, era="pre-b6dfa55"),
        *_run("subgoalvla", 1, {"open_drawer": 10}, era="pre-b6dfa55"),
        *_run("subgoalvla", 2, {"open_drawer": 18}, era="b6dfa55"),
        # two runs whose era the history does not establish: each stays apart, named by its recording commit
        *_run("subgoalvla", 3, {"open_drawer": 4}, era=None, recorded_in="66510f4" + "0" * 33),
        *_run("subgoalvla", 4, {"open_drawer": 6}, era=None, recorded_in="3f76e12" + "0" * 33),
    ]
    lines = tables.table_lines(records, "multi_task")
    assert {line[3]: line[4] for line in lines[1:]} == {
        "pre-b6dfa55": "0,1",
        "b6dfa55": "2",
        "? 66510f4": "3",
        "? 3f76e12": "4",
    }
    assert _row(lines, code="pre-b6dfa55")["mean % (sd, n)"] == "75.0 (sd 35.4, n=2)"
    assert _row(lines, code="b6dfa55")["mean % (sd, n)"] == "90.0 (n=1)"


def test_metaworld_rows_of_one_seed_show_each_tasks_wilson_interval(tables) -> None:
    records = [
        {**r, "setting": "metaworld_mt10", "train_frames": 1679}
        for r in _run("subgoalvla", 0, {"reach-v3": 9, "push-v3": 0})
    ]
    lines = tables.table_lines(records, "metaworld_mt10")
    row = _row(lines, method="subgoalvla")
    assert row["reach-v3"] == "9/20 (26-66 %)" and row["push-v3"] == "0/20 (0-16 %)"
    assert row["mean % (sd, n)"] == "22.5 (n=1)"
    assert tables.table_lines(records, "multi_task") == []  # a table per setting


def test_comparison_columns_name_their_code_era(tables) -> None:
    records = [
        *_run("subgoalvla", 0, {"open_drawer": 19, "close_drawer": 20}, era="pre-b6dfa55"),
        *_run("subgoalvla_no_planner", 1, {"open_drawer": 17, "close_drawer": 20}),
    ]
    lines = tables.comparison_lines(records, ["subgoalvla:0", "subgoalvla_no_planner:1"])
    assert lines[0] == ["task", "subgoalvla:0", "subgoalvla_no_planner:1"]
    assert lines[1] == ["open_drawer", "19/20", "17/20"]
    assert lines[-2] == ["mean", "39/40 = 97.5 %", "37/40 = 92.5 %"]
    assert lines[-1] == ["code era", "pre-b6dfa55", "b6dfa55"]
    with pytest.raises(SystemExit, match="no multi_task records of subgoalvla, seed 5"):
        tables.comparison_lines(records, ["subgoalvla:5"])


def test_a_run_missing_tasks_says_how_many_its_mean_covers(tables) -> None:
    records = [
        {**r, "setting": "metaworld_mt10"}
        for r in [
            *_run("subgoalvla", 0, {"reach-v3": 9, "push-v3": 0, "door-open-v3": 20}),
            *_run("multi_task_dit", 0, {"reach-v3": 6}),  # its evaluation still running
        ]
    ]
    lines = tables.table_lines(records, "metaworld_mt10")
    assert _row(lines, method="multi_task_dit")["mean % (sd, n)"] == "30.0 (n=1) over 1 of 3 tasks"
    assert _row(lines, method="multi_task_dit")["push-v3"] == ""
    assert _row(lines, method="subgoalvla")["mean % (sd, n)"] == "48.3 (n=1)"
