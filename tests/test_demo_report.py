"""subgoalvla-demo-report: exact steps from LeRobot's rounded log, success intervals, the written report."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lerobot_subgoalvla import demo_report

LINE = (
    "INFO 2026-12-01 ot_train.py:641 step:{step} smpl:2K ep:20 epch:0.07 loss:{loss} grdn:2.1 lr:5.5e-04 "
    "updt_s:0.367 data_s:0.368 smp/s:44 planner_loss:{loss} generator_loss:0.3 stage:{stage}.000"
)


def _log(tmp_path: Path, steps: list[str]) -> Path:
    lines = ["Training:  2%|  | 50/3000 [00:36<28:55]"]  # tqdm noise is ignored
    lines += [LINE.format(step=s, loss=1.0 / (i + 1), stage=1 if i < 3 else 2) for i, s in enumerate(steps)]
    lines.append("Training: 100%|██████████| 200/200 [1:02:05<00:00,  1.48step/s]")
    path = tmp_path / "train.log"
    path.write_text("\n".join(lines))
    return path


def test_rounded_steps_are_rebuilt_from_the_log_interval(tmp_path: Path) -> None:
    records = demo_report.parse_train_log(_log(tmp_path, ["250", "500", "1K", "1K", "1K", "2K"]))
    assert [r["step"] for r in records] == [250, 500, 750, 1000, 1250, 1500]
    assert records[0]["smp/s"] == 44 and records[-1]["stage"] == 2


def test_a_resumed_run_keeps_the_rounded_step(tmp_path: Path) -> None:
    records = demo_report.parse_train_log(_log(tmp_path, ["50", "100", "5K"]))
    assert [r["step"] for r in records] == [50, 100, 5000]  # 150 is not within rounding of 5K


def test_wilson_interval_is_sensible_at_the_edges() -> None:
    low, high = demo_report.wilson_interval(10, 10)
    assert high == pytest.approx(1.0) and 0.65 < low < 0.75
    low, high = demo_report.wilson_interval(0, 10)
    assert low == 0.0 and 0.25 < high < 0.35


def test_report_has_success_per_task_chains_and_curves(tmp_path: Path) -> None:
    eval_dir = tmp_path / "eval"
    for task, outcomes in (("open_drawer", [True, True, False, True]), ("turn_on_led", [False, False])):
        (eval_dir / task).mkdir(parents=True)
        info = {
            "per_task": [{"task_id": 0, "metrics": {"successes": outcomes}}],
            "overall": {"video_paths": [str(eval_dir / task / "videos" / "eval_episode_0.mp4")]},
        }
        (eval_dir / task / "eval_info.json").write_text(json.dumps(info))
    chains = eval_dir / "lh_mtlc" / "results.jsonl"
    chains.parent.mkdir()
    record = {
        "chain_id": 0,
        "tasks": ["open_drawer", "turn_on_led", "close_drawer", "move_slider_left", "turn_off_led"],
        "num_completed": 1,
        "outcomes": ["success", "failure", "not_attempted", "not_attempted", "not_attempted"],
        "steps": 400,
        "subtask_steps": [40, 360],
    }
    chains.write_text(json.dumps(record) + "\n")
    out = tmp_path / "report"
    summary = demo_report.build_report(_log(tmp_path, ["50", "100", "150", "200"]), eval_dir, out)
    assert (
        summary["tasks"]["open_drawer"]["successes"] == 3 and summary["tasks"]["turn_on_led"]["rate"] == 0.0
    )
    assert summary["mean_task_success"] == pytest.approx(0.375)
    assert summary["lh_mtlc"]["avg_seq_len"] == pytest.approx(1.0)
    assert (out / "loss_curves.png").stat().st_size > 0 and (out / "task_success.png").stat().st_size > 0
    text = (out / "README.md").read_text()
    assert "37.5 %" in text and "| open_drawer | 3/4 |" in text
    assert "(../eval/open_drawer/videos/eval_episode_0.mp4)" in text  # links stay inside the output tree
    training = json.loads((out / "summary.json").read_text())["training"]
    assert training["steps"] == 200 and training["wall_seconds"] == 3725  # 1:02:05 from the progress bar


def test_cli_refuses_a_missing_eval_dir(tmp_path: Path, caplog) -> None:
    with pytest.raises(SystemExit) as exit_info:  # one line and exit 1, as every subgoalvla-* command
        demo_report.main(["--eval-dir", str(tmp_path / "nope"), "--output-dir", str(tmp_path / "out")])
    assert exit_info.value.code == 1
    assert "--eval-dir" in caplog.text and not (tmp_path / "out").exists()


def test_cli_usage_errors_are_one_line_not_argparse_usage(tmp_path: Path, caplog) -> None:
    with pytest.raises(SystemExit) as exit_info:
        demo_report.main(["--output-dir", str(tmp_path / "out")])  # --eval-dir missing
    assert exit_info.value.code == 1 and "the following arguments are required: --eval-dir" in caplog.text


def test_training_time_of_a_log_kept_without_its_progress_bar(tmp_path: Path) -> None:
    kept = tmp_path / "train.log"  # benchmarks/study/runs/ keep the INFO lines only
    kept.write_text(
        "INFO 2026-12-06 02:54:06 ot_train.py:272 {'batch_size': 32,\n 'steps': 6000}\n"
        "INFO 2026-12-06 02:56:08 ot_train.py:641 step:50 smpl:2K loss:0.338 smp/s:13\n"
        "INFO 2026-12-06 05:17:44 ot_train.py:641 step:6K smpl:192K loss:0.026 smp/s:17\n"
        "INFO 2026-12-06 05:17:50 ot_train.py:700 End of training\n"
    )
    assert demo_report.train_wall_seconds(kept) == 2 * 3600 + 23 * 60 + 38  # first line to last step line
    kept.write_text("INFO 2026-12-06 02:54:06 ot_train.py:298 Creating dataset\n")
    assert demo_report.train_wall_seconds(kept) is None  # never trained a step
