"""``subgoalvla-demo-report``: one page that shows what a training run learned (the main command's last
stage).

Reads what the earlier stages left on disk and writes, into ``--output-dir``:

- ``README.md``: success per single task (with a 95 % Wilson interval), their mean, the LH-1..5 table and
  average length of the chains, training time and throughput, and links to the pictures and rollout videos;
- ``loss_curves.png``: planner and generator loss per logged step from the ``lerobot-train`` log, with the
  stage I -> II switch marked;
- ``task_success.png``: success per task with its interval;
- ``summary.json``: the same numbers, machine-readable.

Inputs: ``--train-log`` (the captured stdout/stderr of ``lerobot-train``; LeRobot logs one ``step:...
loss:...`` line every ``--log_freq`` steps) and ``--eval-dir`` holding one ``lerobot-eval`` output folder per
task (``<task>/eval_info.json``) and ``lh_mtlc/results.jsonl`` from ``--env.results_path``.
"""

from __future__ import annotations

import io
import json
import logging
import math
import os
import re
import sys
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

from lerobot_subgoalvla.calvin_vocab import TASK_NAMES
from lerobot_subgoalvla.cli_errors import OneLineArgumentParser, user_errors

logger = logging.getLogger(__name__)

LH_MTLC_DIR = "lh_mtlc"
_LOG_FIELD = re.compile(r"([\w/]+):([-+0-9.eE]+[KMB]?)(?=\s|$)")
_SUFFIX = {"K": 1e3, "M": 1e6, "B": 1e9}


def _number(text: str) -> float:
    scale = _SUFFIX.get(text[-1], 1.0)
    return float(text[:-1] if scale != 1.0 else text) * scale


def parse_train_log(path: Path) -> list[dict[str, float]]:
    """The metrics of every ``step:...`` line LeRobot logged, with exact step numbers.

    LeRobot prints steps rounded to the nearest thousand from 1000 on (``step:2K`` for 1500..2499); the lines
    come every ``--log_freq`` steps, so a rounded step is replaced by the previous step plus that interval
    (the first two exact steps give it) whenever the rounding allows it; otherwise (a resumed run) the rounded
    value stays.
    """
    records, raw_steps = [], []
    for line in Path(path).read_text(errors="replace").splitlines():
        start = line.find(" step:")
        if start < 0:
            continue
        pairs = _LOG_FIELD.findall(line[start:])
        fields = {key: _number(value) for key, value in pairs}
        if "step" in fields and "loss" in fields:
            records.append(fields)
            raw_steps.append(dict(pairs)["step"])
    exact = [r["step"] for r, text in zip(records, raw_steps, strict=True) if text[-1] not in _SUFFIX]
    interval = exact[1] - exact[0] if len(exact) >= 2 else None
    for i in range(1, len(records)):
        text = raw_steps[i]
        if text[-1] in _SUFFIX and interval is not None:
            predicted = records[i - 1]["step"] + interval
            if abs(predicted - records[i]["step"]) <= _SUFFIX[text[-1]] / 2:
                records[i]["step"] = predicted
    return records


_TQDM_ELAPSED = re.compile(r"Training: *100%\|[^|]*\| *(\d+)/\d+ \[(?:(\d+):)?(\d+):(\d+)<")
_INFO_TIME = re.compile(r"^INFO (\d{4}-\d\d-\d\d \d\d:\d\d:\d\d) ", re.MULTILINE)
_STEP_LINE = re.compile(r" step:\d")


def train_wall_seconds(path: Path) -> float | None:
    """Wall time of the finished training: LeRobot's progress bar (``Training: 100%|...| N/N [MM:SS<``) or,
    in a log kept without it (its ``INFO`` lines only), the time from its first line to its last step line."""
    text = Path(path).read_text(errors="replace")
    matches = _TQDM_ELAPSED.findall(text)
    if matches:
        _, hours, minutes, seconds = matches[-1]
        return 3600 * int(hours or 0) + 60 * int(minutes) + int(seconds)
    stamps = _INFO_TIME.findall(text)
    steps = _INFO_TIME.findall("\n".join(line for line in text.splitlines() if _STEP_LINE.search(line)))
    if not stamps or not steps:
        return None
    return (datetime.fromisoformat(steps[-1]) - datetime.fromisoformat(stamps[0])).total_seconds()


def wilson_interval(successes: int, total: int, z: float = 1.96) -> tuple[float, float]:
    """The 95 % Wilson score interval of a success rate (sensible also at 0/n and n/n)."""
    if total == 0:
        return 0.0, 1.0
    p = successes / total
    centre = (p + z * z / (2 * total)) / (1 + z * z / total)
    half = z * math.sqrt(p * (1 - p) / total + z * z / (4 * total * total)) / (1 + z * z / total)
    return max(0.0, centre - half), min(1.0, centre + half)


def episode_successes(info: dict[str, Any]) -> list[bool]:
    """Per-episode success flags of every task group in a ``lerobot-eval`` ``eval_info.json``."""
    return [bool(s) for entry in info["per_task"] for s in entry["metrics"]["successes"]]


def _task_dirs(eval_dir: Path) -> list[str]:
    """The evaluated tasks: CALVIN's in CALVIN's order, then any other benchmark's (Meta-World) by name."""
    found = {p.parent.name for p in Path(eval_dir).glob("*/eval_info.json")} - {LH_MTLC_DIR}
    return [t for t in TASK_NAMES if t in found] + sorted(found - set(TASK_NAMES))


def read_task_results(eval_dir: Path) -> dict[str, dict[str, Any]]:
    """Task -> successes/episodes/interval/videos from each ``<task>/eval_info.json``."""
    results = {}
    for task in _task_dirs(eval_dir):
        path = Path(eval_dir) / task / "eval_info.json"
        info = json.loads(path.read_text())
        successes = episode_successes(info)
        low, high = wilson_interval(sum(successes), len(successes))
        results[task] = {
            "successes": sum(successes),
            "episodes": len(successes),
            "rate": sum(successes) / len(successes),
            "interval_95": [low, high],
            "videos": [str(p) for p in info.get("overall", {}).get("video_paths", [])],
        }
    return results


def _save(fig: Any, path: Path) -> None:
    from lerobot_subgoalvla.atomic_files import atomic_write

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    atomic_write(path, buffer.getvalue())


def plot_losses(records: Sequence[dict[str, float]], path: Path) -> None:
    """Planner and generator loss (SubgoalVLA) or the total loss (any other policy, e.g. a baseline)
    against the logged step; the stage II steps are shaded."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 4), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    steps = [r["step"] for r in records]
    keys = [k for k in ("planner_loss", "generator_loss") if any(k in r for r in records)] or ["loss"]
    for key, colour in zip(keys, ("tab:purple", "tab:orange"), strict=False):  # keys: present ones only
        ax.plot(steps, [r.get(key, math.nan) for r in records], label=key.replace("_", " "), color=colour)
    stage2 = [r["step"] for r in records if r.get("stage") == 2]
    if stage2:
        ax.axvspan(min(stage2), max(stage2), color="grey", alpha=0.15, label="stage II")
    ax.set(xlabel="optimizer step", ylabel="training loss", yscale="log", title="training losses")
    ax.legend()
    _save(fig, path)


def plot_task_success(tasks: dict[str, dict[str, Any]], path: Path) -> None:
    """Horizontal bars of success per task with the 95 % interval as error bars."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 0.45 * len(tasks) + 1.2), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    names = list(tasks)
    rates = [100 * tasks[t]["rate"] for t in names]
    errors = [
        [100 * (tasks[t]["rate"] - tasks[t]["interval_95"][0]) for t in names],
        [100 * (tasks[t]["interval_95"][1] - tasks[t]["rate"]) for t in names],
    ]
    ax.barh(names, rates, xerr=errors, color="tab:green", capsize=3)
    ax.invert_yaxis()
    ax.set(xlim=(0, 100), xlabel="success rate (%), 95 % interval", title="single tasks, closed loop")
    _save(fig, path)


def _chains(eval_dir: Path) -> dict[str, Any] | None:
    from lerobot_subgoalvla.envs.calvin.evaluation.report import summarize
    from lerobot_subgoalvla.envs.calvin.evaluation.results import read_episode_results

    path = Path(eval_dir) / LH_MTLC_DIR / "results.jsonl"
    if not path.is_file():
        return None
    return summarize(read_episode_results(path)).to_json()


#: Trace figures the end-to-end commands write into the report folder before the report, and their captions.
TRACE_FIGURES = {
    "traces.png": "Predicted subgoal traces (ghost robots) over the executed rollout",
    "trace_plot.png": "Predicted subgoal traces beside the executed state, per state dimension",
}


def _markdown(summary: dict[str, Any], output_dir: Path, title: str) -> str:
    lines = [f"# {title}", ""]
    tasks = summary["tasks"]
    if tasks:
        lines += [
            f"Mean single-task success: **{100 * summary['mean_task_success']:.1f} %** over {len(tasks)} "
            "tasks.",
            "",
            "| task | success | 95 % interval | first video |",
            "| --- | --- | --- | --- |",
        ]
        for task, r in tasks.items():
            low, high = r["interval_95"]
            video = f"[mp4]({os.path.relpath(r['videos'][0], output_dir)})" if r["videos"] else ""
            lines.append(
                f"| {task} | {r['successes']}/{r['episodes']} | {100 * low:.0f}-{100 * high:.0f} % | {video} "
                "|"
            )
        lines += ["", "![success per task](task_success.png)", ""]
    chains = summary["lh_mtlc"]
    if chains:
        rates = " | ".join(f"{100 * chains['chain_sr'][str(k)]:.1f} %" for k in range(1, 6))
        lines += [
            f"LH-MTLC over {chains['num_chains']} chains: average length **{chains['avg_seq_len']:.2f}**",
            "",
            "| LH-1 | LH-2 | LH-3 | LH-4 | LH-5 |",
            "| --- | --- | --- | --- | --- |",
            f"| {rates} |",
            "",
        ]
    train = summary["training"]
    if train:
        minutes = "" if train["wall_seconds"] is None else f" in {train['wall_seconds'] / 60:.0f} min"
        losses = ", ".join(f"{name.replace('_', ' ')} {value:.4f}" for name, value in train["losses"].items())
        lines += [
            f"Training: {train['steps']:.0f} steps{minutes}, last {losses}, "
            f"{train['samples_per_s']:.0f} samples/s.",
            "",
            "![loss curves](loss_curves.png)",
            "",
        ]
    for name, caption in TRACE_FIGURES.items():
        if (output_dir / name).is_file():
            lines += [f"{caption}: ![traces]({name})", ""]
    return "\n".join(lines)


def build_report(
    train_log: Path | None, eval_dir: Path, output_dir: Path, title: str = "SubgoalVLA demo report"
) -> dict[str, Any]:
    """Write README.md, summary.json and the PNGs into ``output_dir``; returns the summary."""
    output_dir.mkdir(parents=True, exist_ok=True)
    tasks = read_task_results(eval_dir)
    records = parse_train_log(train_log) if train_log is not None else []
    last = records[-1] if records else None
    training = None
    if last is not None:
        training = {
            "steps": last["step"],
            "wall_seconds": train_wall_seconds(train_log),
            "losses": {k: last[k] for k in ("planner_loss", "generator_loss") if k in last}
            or {"loss": last["loss"]},
            "samples_per_s": last.get("smp/s", math.nan),
        }
        plot_losses(records, output_dir / "loss_curves.png")
    if tasks:
        plot_task_success(tasks, output_dir / "task_success.png")
    summary = {
        "tasks": tasks,
        "mean_task_success": sum(r["rate"] for r in tasks.values()) / len(tasks) if tasks else None,
        "lh_mtlc": _chains(eval_dir),
        "training": training,
    }
    (output_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    (output_dir / "README.md").write_text(_markdown(summary, output_dir, title))
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``subgoalvla-demo-report``."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    parser = OneLineArgumentParser(prog="subgoalvla-demo-report", description=__doc__.splitlines()[0])
    parser.add_argument("--train-log", type=Path, default=None, help="captured output of lerobot-train")
    parser.add_argument(
        "--eval-dir", type=Path, required=True, help="folder of <task>/eval_info.json and lh_mtlc/"
    )
    parser.add_argument("--output-dir", type=Path, required=True, help="where README.md and the PNGs go")
    parser.add_argument("--title", default="SubgoalVLA demo report", help="the report's heading")
    with user_errors(logger):
        args = parser.parse_args(argv)
        for flag, path in (("--train-log", args.train_log), ("--eval-dir", args.eval_dir)):
            if path is not None and not path.exists():
                raise FileNotFoundError(f"{flag} {path} does not exist; run the earlier demo stages first")
        summary = build_report(args.train_log, args.eval_dir, args.output_dir, args.title)
    mean = summary["mean_task_success"]
    chains = summary["lh_mtlc"]
    logger.info(
        "mean single-task success %s; LH-MTLC average length %s; report %s",
        "n/a" if mean is None else f"{100 * mean:.1f} %",
        "n/a" if chains is None else f"{chains['avg_seq_len']:.2f} over {chains['num_chains']} chains",
        args.output_dir / "README.md",
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
