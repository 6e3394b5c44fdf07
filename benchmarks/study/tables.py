"""Print the study's tables from ``benchmarks/study/results.json`` (no training, no simulator).

One row per (method, setting, training samples, training frames): closed-loop success per task (successes
over episodes, summed over the seeds), the mean success over the tasks with its spread over training seeds
(mean +- half the range of the per-seed means; one seed: no spread), and the cost: training wall time,
training samples/s and evaluation seconds per episode (medians over the seeds). For ``lh_mtlc`` the cell is
the average chain length (tasks completed in a row, 0-5) over the seeds' chains.

Usage::

    python benchmarks/study/tables.py                      # every setting
    python benchmarks/study/tables.py --setting multi_task --markdown
    python benchmarks/study/tables.py --compare subgoalvla:0 subgoalvla:1 subgoalvla_mean_pool:0 --markdown

``--compare`` prints one column per run (``METHOD:SEED``, optionally ``METHOD:SEED:SAMPLES`` where a method
has runs of several budgets, default 80000 samples, and ``METHOD:SEED:SAMPLES:FRAMES`` where it has runs on
several generations of the data) and one row per task, with a pooled mean row.
"""

from __future__ import annotations

import argparse
import statistics
from collections import defaultdict

from common import FIXTURE_TASKS
from records import load_records

COLUMNS = ("o_drawer", "c_drawer", "slider_l", "slider_r", "on_led", "off_led", "on_bulb", "off_bulb")
SHORT = dict(zip(FIXTURE_TASKS, COLUMNS, strict=True))


def _group(records: list[dict], setting: str) -> dict[tuple, list[dict]]:
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for record in records:
        if record["setting"] == setting:
            key = (record["method"], record["train_samples"], record.get("train_frames") or 0)
            groups[key].append(record)
    return groups


def _median(values: list) -> float | None:
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def summarize(rows: list[dict]) -> dict:
    """Per-task totals, per-seed mean success, and the cost medians of one group of records."""
    per_task: dict[str, list[float]] = defaultdict(lambda: [0, 0])
    per_seed: dict[int, list[float]] = defaultdict(lambda: [0, 0])
    for r in rows:
        # lh_mtlc: the score is the average length (x chains, so that sums over seeds weigh chains equally)
        score = r["avg_len"] * r["episodes"] if r["setting"] == "lh_mtlc" else 100 * r["successes"]
        for totals in (per_task[r["task"]], per_seed[r["seed"]]):
            totals[0] += score
            totals[1] += r["episodes"]
    seed_means = [s / n for s, n in per_seed.values()]
    spread = (max(seed_means) - min(seed_means)) / 2 if len(seed_means) > 1 else None
    return {
        "per_task": dict(per_task),
        "seeds": sorted(per_seed),
        "mean": statistics.mean(seed_means),
        "spread": spread,
        "train_seconds": _median([r.get("train_seconds") for r in rows]),
        "samples_per_s": _median([r.get("samples_per_s") for r in rows]),
        "eval_s_per_episode": _median([r.get("eval_seconds_per_episode") for r in rows]),
    }


def _cell(totals: list[float] | None, setting: str) -> str:
    if totals is None:
        return ""
    score, episodes = totals
    return f"{score / episodes:.2f} ({episodes})" if setting == "lh_mtlc" else f"{score / 100:.0f}/{episodes}"


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def print_table(records: list[dict], setting: str, markdown: bool) -> None:
    groups = _group(records, setting)
    if not groups:
        return
    tasks = [t for t in FIXTURE_TASKS if any(r["task"] == t for rows in groups.values() for r in rows)]
    tasks += sorted({r["task"] for rows in groups.values() for r in rows} - set(tasks))
    score = "avg len" if setting == "lh_mtlc" else "mean %"
    head = ["method", "samples", "frames", "seeds", *(SHORT.get(t, t) for t in tasks), score, "train min",
            "smp/s", "eval s/ep"]  # fmt: skip
    lines = [head]
    for (method, samples, frames), rows in sorted(groups.items()):
        s = summarize(rows)
        cells = [_cell(s["per_task"].get(t), setting) for t in tasks]
        digits = ".2f" if setting == "lh_mtlc" else ".1f"
        mean = format(s["mean"], digits) + ("" if s["spread"] is None else f" +- {s['spread']:{digits}}")
        minutes = None if s["train_seconds"] is None else s["train_seconds"] / 60
        lines.append([method, str(samples), str(frames or "-"), ",".join(map(str, s["seeds"])), *cells, mean,
                      _fmt(minutes, ".1f"), _fmt(s["samples_per_s"], ".0f"),
                      _fmt(s["eval_s_per_episode"], ".1f")])  # fmt: skip
    print(f"\n{setting}  (tasks: {', '.join(f'{SHORT.get(t, t)}={t}' for t in tasks)})")
    _print_lines(lines, markdown)


def _print_lines(lines: list[list[str]], markdown: bool) -> None:
    """A header line and rows, as a Markdown table or as aligned text (first column left, the rest right)."""
    if markdown:
        print("| " + " | ".join(lines[0]) + " |")
        print("|" + " --- |" * len(lines[0]))
        for line in lines[1:]:
            print("| " + " | ".join(line) + " |")
        return
    widths = [max(len(line[i]) for line in lines) for i in range(len(lines[0]))]
    for line in lines:
        print(
            "  ".join(
                cell.rjust(w) if i else cell.ljust(w)
                for i, (cell, w) in enumerate(zip(line, widths, strict=True))
            )
        )


def _run_records(records: list[dict], run: str) -> list[dict]:
    method, seed, *rest = run.split(":")
    budget = int(rest[0]) if rest else 80000
    wanted = (method, "multi_task", int(seed), budget)
    rows = [r for r in records if (r["method"], r["setting"], r["seed"], r["train_samples"]) == wanted]
    if len(rest) > 1:
        rows = [r for r in rows if r.get("train_frames") == int(rest[1])]
    if not rows:
        raise SystemExit(f"--compare {run}: no multi_task records of {method}, seed {seed}, {budget} samples")
    frames = sorted({r.get("train_frames") or 0 for r in rows})
    if len(frames) > 1:
        raise SystemExit(
            f"--compare {run}: runs on datasets of {frames} frames; name one: {method}:{seed}:{budget}:FRAMES"
        )
    return rows


def print_comparison(records: list[dict], runs: list[str], markdown: bool) -> None:
    """Task rows x run columns: ``successes/episodes`` per task, then the pooled mean success."""
    columns = {run: {r["task"]: r for r in _run_records(records, run)} for run in runs}
    lines = [["task", *runs]]
    for task in FIXTURE_TASKS:
        cells = [columns[run].get(task) for run in runs]
        lines.append([task, *("" if c is None else f"{c['successes']}/{c['episodes']}" for c in cells)])
    means = []
    for run in runs:
        done, total = (sum(r[key] for r in columns[run].values()) for key in ("successes", "episodes"))
        means.append(f"{done}/{total} = {100 * done / total:.1f} %")
    lines.append([f"**{cell}**" for cell in ("mean", *means)] if markdown else ["mean", *means])
    _print_lines(lines, markdown)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--setting", choices=["single_task", "multi_task", "lh_mtlc"], default=None)
    parser.add_argument("--markdown", action="store_true", help="print Markdown tables")
    parser.add_argument(
        "--compare",
        nargs="+",
        metavar="METHOD:SEED[:SAMPLES[:FRAMES]]",
        help="one column per multi-task run, one row per task (e.g. subgoalvla:0 subgoalvla_mean_pool:0)",
    )
    args = parser.parse_args()
    records = load_records()
    if args.compare:
        print_comparison(records, args.compare, args.markdown)
        return
    for setting in [args.setting] if args.setting else ["single_task", "multi_task", "lh_mtlc"]:
        print_table(records, setting, args.markdown)


if __name__ == "__main__":
    main()
