"""Print the study's tables from ``benchmarks/study/results.json`` (from the records alone: nothing runs).

One table per setting, one row per (method, training samples, training frames, code era): runs of different
training code are never pooled (``records.ERA_COMMITS``; a record whose era the history does not establish
is a row of its own, named by the commit that recorded it). Columns: closed-loop success per task
(successes over episodes, summed over the row's seeds; for a row of one seed in a setting of
:data:`INTERVAL_SETTINGS`, with its 95 % Wilson interval), the mean success over the tasks: the mean over
seeds of each seed's mean with the sample standard deviation and the number of seeds (``82.5 (sd 6.0, n=3)``),
the range of the seeds' means, and the cost: training wall time, training samples/s and evaluation seconds
per episode (medians over the seeds). For ``lh_mtlc`` the score is the average chain length (tasks completed
in a row, 0-5).

Usage::

    python benchmarks/study/tables.py                      # every setting
    python benchmarks/study/tables.py --setting multi_task --markdown
    python benchmarks/study/tables.py --compare subgoalvla:0 subgoalvla:1 subgoalvla_mean_pool:0 --markdown

``--compare`` prints one column per run (``METHOD:SEED``, optionally ``METHOD:SEED:SAMPLES`` where a method
has runs of several budgets, default 80000 samples, and ``METHOD:SEED:SAMPLES:FRAMES`` where it has runs on
several generations of the data) and one row per task, then the pooled mean and each run's code era; the runs
are those of ``--setting`` (default multi_task).
"""

from __future__ import annotations

import argparse
import statistics
from collections import defaultdict

from common import FIXTURE_TASKS, LH_MTLC
from records import load_records

SETTINGS = ("single_task", "multi_task", LH_MTLC, "metaworld_mt10", "metaworld_mt10_heldout")
#: Settings whose one-seed rows show each task's 95 % Wilson interval beside its successes.
INTERVAL_SETTINGS = frozenset({"metaworld_mt10", "metaworld_mt10_heldout"})
COLUMNS = ("o_drawer", "c_drawer", "slider_l", "slider_r", "on_led", "off_led", "on_bulb", "off_bulb")
SHORT = dict(zip(FIXTURE_TASKS, COLUMNS, strict=True))


def era_label(record: dict) -> str:
    """The code era a record ran (``code_era``); where it is not established, ``?`` and the commit that
    recorded the run (so two such runs are never pooled); else its commit."""
    if record.get("code_era"):
        return record["code_era"]
    if record.get("recorded_in"):
        return f"? {record['recorded_in'][:7]}"
    return f"? {(record.get('commit') or 'unrecorded')[:7]}"


def _group(records: list[dict], setting: str) -> dict[tuple, list[dict]]:
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for record in records:
        if record["setting"] == setting:
            key = (
                record["method"],
                record["train_samples"],
                record.get("train_frames") or 0,
                era_label(record),
            )
            groups[key].append(record)
    return groups


def _median(values: list) -> float | None:
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def summarize(rows: list[dict]) -> dict:
    """Per-task totals, per-seed means and their spread (mean, sample sd, range, n), and the cost medians
    of one group of records."""
    per_task: dict[str, list[float]] = defaultdict(lambda: [0, 0])
    per_seed: dict[int, list[float]] = defaultdict(lambda: [0, 0])
    for r in rows:
        # lh_mtlc: the score is the average length (x chains, so that sums over seeds weigh chains equally)
        score = r["avg_len"] * r["episodes"] if r["setting"] == LH_MTLC else 100 * r["successes"]
        for totals in (per_task[r["task"]], per_seed[r["seed"]]):
            totals[0] += score
            totals[1] += r["episodes"]
    seed_means = [per_seed[seed][0] / per_seed[seed][1] for seed in sorted(per_seed)]
    return {
        "per_task": dict(per_task),
        "seeds": sorted(per_seed),
        "seed_means": seed_means,
        "mean": statistics.mean(seed_means),
        "sd": statistics.stdev(seed_means) if len(seed_means) > 1 else None,
        "range": (min(seed_means), max(seed_means)) if len(seed_means) > 1 else None,
        "train_seconds": _median([r.get("train_seconds") for r in rows]),
        "samples_per_s": _median([r.get("samples_per_s") for r in rows]),
        "eval_s_per_episode": _median([r.get("eval_seconds_per_episode") for r in rows]),
    }


def spread_text(summary: dict, digits: str = ".1f") -> str:
    """``mean (sd S, n=N)``: the mean over seeds, their sample standard deviation and how many seeds."""
    n = len(summary["seeds"])
    if summary["sd"] is None:
        return f"{summary['mean']:{digits}} (n={n})"
    return f"{summary['mean']:{digits}} (sd {summary['sd']:{digits}}, n={n})"


def _cell(totals: list[float] | None, setting: str, interval: bool) -> str:
    if totals is None:
        return ""
    score, episodes = totals
    if setting == LH_MTLC:
        return f"{score / episodes:.2f} ({episodes})"
    successes = round(score / 100)
    if not interval:
        return f"{successes}/{episodes}"
    from lerobot_subgoalvla.demo_report import wilson_interval

    low, high = wilson_interval(successes, episodes)
    return f"{successes}/{episodes} ({100 * low:.0f}-{100 * high:.0f} %)"


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _tasks(records: list[dict]) -> list[str]:
    """The records' tasks: the fixture tasks in their order, then the others sorted."""
    names = {r["task"] for r in records}
    return [t for t in FIXTURE_TASKS if t in names] + sorted(names - set(FIXTURE_TASKS))


def table_lines(records: list[dict], setting: str) -> list[list[str]]:
    """The header and one row per (method, samples, frames, code era) of ``setting``; [] when it has none."""
    groups = _group(records, setting)
    if not groups:
        return []
    tasks = _tasks([r for rows in groups.values() for r in rows])
    score = "avg len" if setting == LH_MTLC else "mean %"
    digits = ".2f" if setting == LH_MTLC else ".1f"
    head = ["method", "samples", "frames", "code", "seeds", *(SHORT.get(t, t) for t in tasks),
            f"{score} (sd, n)", "seed range", "train min", "smp/s", "eval s/ep"]  # fmt: skip
    lines = [head]
    for (method, samples, frames, era), rows in sorted(groups.items()):
        s = summarize(rows)
        interval = setting in INTERVAL_SETTINGS and len(s["seeds"]) == 1
        cells = [_cell(s["per_task"].get(t), setting, interval) for t in tasks]
        span = "-" if s["range"] is None else f"{s['range'][0]:{digits}}-{s['range'][1]:{digits}}"
        minutes = None if s["train_seconds"] is None else s["train_seconds"] / 60
        score_text = spread_text(s, digits)
        if len(s["per_task"]) < len(tasks):  # a run still being evaluated: its mean is not the table's
            score_text += f" over {len(s['per_task'])} of {len(tasks)} tasks"
        lines.append([method, str(samples), str(frames or "-"), era, ",".join(map(str, s["seeds"])), *cells,
                      score_text, span, _fmt(minutes, ".1f"), _fmt(s["samples_per_s"], ".0f"),
                      _fmt(s["eval_s_per_episode"], ".1f")])  # fmt: skip
    return lines


def print_table(records: list[dict], setting: str, markdown: bool) -> None:
    lines = table_lines(records, setting)
    if not lines:
        return
    legend = [
        f"{SHORT[t]}={t}" for t in _tasks([r for r in records if r["setting"] == setting]) if t in SHORT
    ]
    print(f"\n{setting}" + (f"  (tasks: {', '.join(legend)})" if legend else ""))
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


def _run_records(records: list[dict], run: str, setting: str) -> list[dict]:
    method, seed, *rest = run.split(":")
    budget = int(rest[0]) if rest else 80000
    wanted = (method, setting, int(seed), budget)
    rows = [r for r in records if (r["method"], r["setting"], r["seed"], r["train_samples"]) == wanted]
    if len(rest) > 1:
        rows = [r for r in rows if r.get("train_frames") == int(rest[1])]
    if not rows:
        raise SystemExit(f"--compare {run}: no {setting} records of {method}, seed {seed}, {budget} samples")
    frames = sorted({r.get("train_frames") or 0 for r in rows})
    if len(frames) > 1:
        raise SystemExit(
            f"--compare {run}: runs on datasets of {frames} frames; name one: {method}:{seed}:{budget}:FRAMES"
        )
    return rows


def comparison_lines(records: list[dict], runs: list[str], setting: str = "multi_task") -> list[list[str]]:
    """Task rows x run columns: ``successes/episodes`` per task, the pooled mean success, each run's era."""
    selected = {run: _run_records(records, run, setting) for run in runs}
    columns = {run: {r["task"]: r for r in rows} for run, rows in selected.items()}
    lines = [["task", *runs]]
    for task in _tasks([r for rows in selected.values() for r in rows]):
        cells = [columns[run].get(task) for run in runs]
        lines.append([task, *("" if c is None else f"{c['successes']}/{c['episodes']}" for c in cells)])
    means = []
    for run in runs:
        done, total = (sum(r[key] for r in columns[run].values()) for key in ("successes", "episodes"))
        means.append(f"{done}/{total} = {100 * done / total:.1f} %")
    lines.append(["mean", *means])
    lines.append(["code era", *(" / ".join(sorted({era_label(r) for r in selected[run]})) for run in runs)])
    return lines


def print_comparison(records: list[dict], runs: list[str], markdown: bool, setting: str) -> None:
    lines = comparison_lines(records, runs, setting)
    if markdown:
        lines[-2] = [f"**{cell}**" for cell in lines[-2]]
    _print_lines(lines, markdown)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--setting", choices=SETTINGS, default=None, help="one table (default: every setting)"
    )
    parser.add_argument("--markdown", action="store_true", help="print Markdown tables")
    parser.add_argument(
        "--compare",
        nargs="+",
        metavar="METHOD:SEED[:SAMPLES[:FRAMES]]",
        help="one column per run of --setting (default multi_task), one row per task (e.g. subgoalvla:0)",
    )
    args = parser.parse_args()
    records = load_records()
    if args.compare:
        print_comparison(records, args.compare, args.markdown, args.setting or "multi_task")
        return
    for setting in [args.setting] if args.setting else SETTINGS:
        print_table(records, setting, args.markdown)


if __name__ == "__main__":
    main()
