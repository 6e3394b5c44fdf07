"""LH-MTLC report (spec 4.4): metrics on hand-made results, JSON/PNG outputs, shards, bad input."""

from __future__ import annotations

import json
import logging
import struct
from pathlib import Path

import pytest

from lerobot_subgoalvla.envs.calvin.evaluation.chains import generate_chains, save_chains
from lerobot_subgoalvla.envs.calvin.evaluation.report import format_report, main, summarize
from lerobot_subgoalvla.envs.calvin.evaluation.results import EpisodeResult, append_episode_result

A = ("open_drawer", "turn_on_led", "lift_red_block_table", "place_in_drawer", "move_slider_left")
B = ("close_drawer", "turn_off_led", "lift_blue_block_table", "stack_block", "move_slider_right")

#: Results 5, 3, 0, 1 -> SR_1 = 3/4, SR_2 = 2/4, SR_3 = 2/4, SR_4 = 1/4, SR_5 = 1/4; average length 9/4.
HAND_MADE = [EpisodeResult(0, A, 5), EpisodeResult(1, A, 3), EpisodeResult(2, B, 0), EpisodeResult(3, B, 1)]


def test_summary_math() -> None:
    report = summarize(HAND_MADE)
    assert report.num_chains == 4
    assert report.chain_sr == {1: 0.75, 2: 0.5, 3: 0.5, 4: 0.25, 5: 0.25}
    assert report.avg_seq_len == pytest.approx(sum(report.chain_sr.values())) == 2.25
    info = report.task_info
    assert info["open_drawer"] == {"success": 2, "total": 2}
    assert info["turn_on_led"] == {"success": 2, "total": 2}
    assert info["lift_red_block_table"] == {"success": 2, "total": 2}
    assert info["place_in_drawer"] == {"success": 1, "total": 2}  # chain 1 failed here
    assert info["move_slider_left"] == {"success": 1, "total": 1}  # chain 1 never reached it: not counted
    assert info["close_drawer"] == {"success": 1, "total": 2}  # chain 2 failed at once, chain 3 succeeded
    assert info["turn_off_led"] == {"success": 0, "total": 1}
    assert set(info) == {
        "open_drawer",
        "turn_on_led",
        "lift_red_block_table",
        "place_in_drawer",
        "move_slider_left",
        "close_drawer",
        "turn_off_led",
    }
    text = format_report(report)
    assert "LH-1:  75.0%" in text and "LH-5:  25.0%" in text and "2.250" in text


def test_summary_rejects_empty() -> None:
    with pytest.raises(ValueError, match="No episode results"):
        summarize([])


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def _write_jsonl(path: Path, results: list[EpisodeResult]) -> Path:
    for result in results:
        append_episode_result(path, result)
    return path


def test_cli_jsonl_shards(tmp_path: Path) -> None:
    shard0 = _write_jsonl(tmp_path / "shard0.jsonl", HAND_MADE[:2])
    shard1 = _write_jsonl(tmp_path / "shard1.jsonl", HAND_MADE[2:])
    out = tmp_path / "report"
    assert main([str(shard1), str(shard0), "--output-dir", str(out)]) == 0
    data = json.loads((out / "results.json").read_text())
    assert set(data) == {"avg_seq_len", "chain_sr", "task_info", "num_chains"}
    assert data["avg_seq_len"] == 2.25 and data["num_chains"] == 4
    assert data["chain_sr"] == {"1": 0.75, "2": 0.5, "3": 0.5, "4": 0.25, "5": 0.25}
    assert data["task_info"]["place_in_drawer"] == {"success": 1, "total": 2}
    width, height = _png_size(out / "results.png")
    assert width == 1200 and height == 600


def test_cli_eval_info_with_chains_file(tmp_path: Path) -> None:
    chains = generate_chains(10)
    chains_path = tmp_path / "chains.json"
    save_chains(chains_path, chains)
    # lerobot-eval: one task_id per chain, sum_rewards = completed subtasks (one episode each)
    shard_a = {
        "per_task": [
            {"task_group": "calvin", "task_id": 0, "metrics": {"sum_rewards": [2.0]}},
            {"task_group": "calvin", "task_id": 1, "metrics": {"sum_rewards": [5.0]}},
        ]
    }
    shard_b = {"per_task": [{"task_group": "calvin", "task_id": 7, "metrics": {"sum_rewards": [0.0]}}]}
    (tmp_path / "a.json").write_text(json.dumps(shard_a))
    (tmp_path / "b.json").write_text(json.dumps(shard_b))
    out = tmp_path / "out"
    argv = [
        str(tmp_path / "a.json"),
        str(tmp_path / "b.json"),
        "--output-dir",
        str(out),
        "--chains",
        str(chains_path),
    ]
    assert main(argv) == 0
    data = json.loads((out / "results.json").read_text())
    assert data["num_chains"] == 3 and data["avg_seq_len"] == pytest.approx(7 / 3)
    assert data["chain_sr"]["1"] == pytest.approx(2 / 3) and data["chain_sr"]["5"] == pytest.approx(1 / 3)
    failed_first = chains[7].tasks[0]
    assert data["task_info"][failed_first]["total"] >= 1
    assert sum(v["total"] for v in data["task_info"].values()) == 3 + 5 + 1


def _bad_inputs(tmp_path: Path) -> dict[str, list[str]]:
    good = _write_jsonl(tmp_path / "good.jsonl", HAND_MADE[:2])
    dup = _write_jsonl(tmp_path / "dup.jsonl", HAND_MADE[1:3])  # chain 1 is in both shards
    malformed = tmp_path / "malformed.jsonl"
    malformed.write_text('{"chain_id": 0, "tasks": []}\n{not json\n')
    wrong_count = tmp_path / "eval_info.json"
    wrong_count.write_text(json.dumps({"per_task": [{"task_id": 0, "metrics": {"sum_rewards": [1.0, 2.0]}}]}))
    return {
        "missing": [str(tmp_path / "nope.jsonl")],
        "duplicate": [str(good), str(dup)],
        "malformed": [str(malformed)],
        "n_episodes": [str(wrong_count), "--num-chains", "10"],
        "chain_id_out_of_range": [
            str(_write_jsonl(tmp_path / "far.jsonl", HAND_MADE[:2])),
            "--num-chains",
            "1",
        ],
    }


@pytest.mark.parametrize("case", ["missing", "duplicate", "malformed", "n_episodes", "chain_id_out_of_range"])
def test_cli_bad_input(tmp_path: Path, caplog: pytest.LogCaptureFixture, case: str) -> None:
    argv = _bad_inputs(tmp_path)[case] + ["--output-dir", str(tmp_path / "out")]
    with caplog.at_level(logging.ERROR), pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 1
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1 and "\n" not in errors[0]
    assert not (tmp_path / "out" / "results.json").exists()


def test_console_scripts_resolve() -> None:
    from importlib.metadata import entry_points

    from lerobot_subgoalvla.envs.calvin.evaluation.chains import main as chains_main

    scripts = {ep.name: ep for ep in entry_points(group="console_scripts")}
    assert scripts["subgoalvla-calvin-report"].load() is main
    assert scripts["subgoalvla-calvin-chains"].load() is chains_main
