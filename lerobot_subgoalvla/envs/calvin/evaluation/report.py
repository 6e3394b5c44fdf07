"""``subgoalvla-calvin-report``: CALVIN's long-horizon metrics from per-episode results (docs/calvin.md 4.4).

Reads the results of one or several shards - JSON lines written by the env (``--env.results_path``) or the
``eval_info.json`` of ``lerobot-eval`` - merges them by chain id (a chain seen twice is an error) and reports
what CALVIN's ``print_and_save`` reports:

- ``SR_k`` = #(chains with at least k subtasks completed in a row) / N, k = 1..5 (the "LH-k" table);
- the average length = mean number of completed subtasks = sum_k SR_k (0..5);
- per task ``success / total``: the subtasks before a chain's failure succeed, the failed one fails, later
  ones are not counted.

Outputs: the table in the log, ``results.json`` (CALVIN's structure: ``avg_seq_len``, ``chain_sr`` {1..5},
``task_info`` {task: {success, total}}, plus ``num_chains``) and ``results.png`` (LH-1..5 bars and per-task
success bars, like figure 5 of the SubgoalVLA paper).

Usage::

    subgoalvla-calvin-report outputs/eval/calvin/results.jsonl --output-dir outputs/eval/calvin
    subgoalvla-calvin-report shard0/eval_info.json shard1/eval_info.json --output-dir report --chains
    chains.json
"""

from __future__ import annotations

import io
import json
import logging
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lerobot_subgoalvla.atomic_files import atomic_write
from lerobot_subgoalvla.calvin_vocab import TASK_NAMES
from lerobot_subgoalvla.cli_errors import OneLineArgumentParser, user_errors
from lerobot_subgoalvla.envs.calvin.evaluation.chains import (
    configure_cli_logging,
    generate_chains,
    load_chains,
)
from lerobot_subgoalvla.envs.calvin.evaluation.results import (
    NOT_ATTEMPTED,
    SUCCESS,
    EpisodeResult,
    episode_results_from_eval_info,
    merge_results,
    read_episode_results,
)
from lerobot_subgoalvla.envs.calvin.protocol import CHAIN_LENGTH

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class LongHorizonReport:
    """CALVIN's LH-MTLC summary of N evaluated chains.

    Args:
        num_chains: N, the number of evaluated chains.
        chain_sr: k -> SR_k, the fraction of chains with at least k subtasks completed in a row (k = 1..5).
        avg_seq_len: mean number of completed subtasks per chain (= sum of ``chain_sr``).
        task_info: task -> {"success": n, "total": m}, in CALVIN's task-id order.
    """

    num_chains: int
    chain_sr: Mapping[int, float]
    avg_seq_len: float
    task_info: Mapping[str, Mapping[str, int]]

    def to_json(self) -> dict[str, Any]:
        return {
            "avg_seq_len": self.avg_seq_len,
            "chain_sr": {str(k): v for k, v in self.chain_sr.items()},
            "task_info": {t: dict(v) for t, v in self.task_info.items()},
            "num_chains": self.num_chains,
        }


def summarize(results: Sequence[EpisodeResult]) -> LongHorizonReport:
    """CALVIN's ``count_success`` + ``print_and_save`` arithmetic over ``results`` (spec 4.4)."""
    if not results:
        raise ValueError("No episode results to report")
    n = len(results)
    counts = Counter(r.num_completed for r in results)
    chain_sr = {k: sum(counts[j] for j in range(k, CHAIN_LENGTH + 1)) / n for k in range(1, CHAIN_LENGTH + 1)}
    success, total = Counter[str](), Counter[str]()
    for result in results:
        for task, outcome in zip(result.tasks, result.outcomes, strict=True):
            if outcome != NOT_ATTEMPTED:
                total[task] += 1
                success[task] += int(outcome == SUCCESS)
    task_info = {t: {"success": success[t], "total": total[t]} for t in TASK_NAMES if total[t]}
    avg = sum(r.num_completed for r in results) / n
    return LongHorizonReport(n, chain_sr, avg, task_info)


def format_report(report: LongHorizonReport) -> str:
    """The report as CALVIN prints it: average length, ``k: xx.x%`` rows, per-task ``success / total``."""
    lines = [
        f"Evaluated chains: {report.num_chains}",
        f"Average successful sequence length: {report.avg_seq_len:.3f}",
        "Success rates for k instructions in a row:",
    ]
    lines += [f"  LH-{k}: {sr * 100:5.1f}%" for k, sr in report.chain_sr.items()]
    width = max((len(t) for t in report.task_info), default=0)
    for task, info in report.task_info.items():
        rate = info["success"] / info["total"] * 100
        lines.append(f"  {task:<{width}}  {info['success']:4d} / {info['total']:<4d} SR {rate:5.1f}%")
    return "\n".join(lines)


def plot_report(report: LongHorizonReport, path: Path) -> None:
    """Bar charts of LH-1..5 and of per-task success rates, written as a PNG (Agg canvas, no pyplot state)."""
    from matplotlib.backends.backend_agg import (
        FigureCanvasAgg,  # here: --help and the text report need no plots
    )
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 6), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    lh_ax, task_ax = fig.subplots(1, 2, width_ratios=(1, 2))
    ks, rates = list(report.chain_sr), [100 * sr for sr in report.chain_sr.values()]
    bars = lh_ax.bar([f"LH-{k}" for k in ks], rates, color="tab:blue")
    lh_ax.bar_label(bars, fmt="%.1f")
    lh_ax.set(ylim=(0, 105), ylabel="success rate (%)",
              title=f"{report.num_chains} chains, avg. len {report.avg_seq_len:.2f}")  # fmt: skip
    tasks = list(report.task_info)
    task_rates = [100 * report.task_info[t]["success"] / report.task_info[t]["total"] for t in tasks]
    task_ax.barh(tasks, task_rates, color="tab:green")
    task_ax.invert_yaxis()
    task_ax.tick_params(axis="y", labelsize=7)
    task_ax.set(xlim=(0, 100), xlabel="success rate (%)", title="per task (attempted subtasks)")
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    atomic_write(path, buffer.getvalue())


def load_results(paths: Sequence[Path], chains_path: Path | None, num_chains: int) -> list[EpisodeResult]:
    """Read every results file (JSON lines or ``eval_info.json``) and merge the shards by chain id.

    The chain list (``chains_path``, else CALVIN's generator with ``num_chains``) maps ``eval_info.json``'s
    task ids to chains and cross-checks the task names of JSON-lines records.
    """
    chain_tasks: dict[int, tuple[str, ...]] | None = None

    def tasks_by_chain() -> dict[int, tuple[str, ...]]:
        nonlocal chain_tasks
        if chain_tasks is None:
            chains = load_chains(chains_path) if chains_path else dict(enumerate(generate_chains(num_chains)))
            chain_tasks = {cid: chain.tasks for cid, chain in chains.items()}
        return chain_tasks

    shards: dict[str, list[EpisodeResult]] = {}
    for path in map(Path, paths):
        if not path.is_file():
            raise FileNotFoundError(f"Results file {path} not found")
        try:
            content = json.loads(path.read_text())
        except json.JSONDecodeError:
            content = None  # several lines: JSON lines, parsed (and checked) below
        if isinstance(content, Mapping) and "per_task" in content:
            shards[str(path)] = episode_results_from_eval_info(content, tasks_by_chain())
        else:
            shards[str(path)] = read_episode_results(path)
    results = merge_results(shards)
    # A chain id outside the list means results of another list (or a damaged file), which would otherwise
    # be counted silently; the tasks are compared when the evaluation's own list is given.
    if chains_path is None:
        for result in results:
            if not 0 <= result.chain_id < num_chains:
                raise ValueError(
                    f"chain {result.chain_id}: not one of CALVIN's {num_chains} chains (ids 0.."
                    f"{num_chains - 1}); pass the evaluation's chain list with --chains, or --num-chains"
                )
    else:
        known = tasks_by_chain()
        for result in results:
            if known.get(result.chain_id) != result.tasks:
                raise ValueError(f"chain {result.chain_id}: tasks {result.tasks} differ from {chains_path}")
    return results


def _parse_args(argv: Sequence[str] | None) -> Any:
    parser = OneLineArgumentParser(prog="subgoalvla-calvin-report", description=__doc__.split("\n")[0])
    parser.add_argument(
        "results", type=Path, nargs="+", help="results.jsonl or eval_info.json files (shards)"
    )
    parser.add_argument("--output-dir", type=Path, required=True, help="where results.json/results.png go")
    parser.add_argument("--chains", type=Path, default=None, help="chains.json used by the evaluation")
    parser.add_argument(
        "--num-chains", type=int, default=1000, help="chain list size when --chains is absent"
    )
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    """``subgoalvla-calvin-report``: log the LH table, write results.json and results.png."""
    configure_cli_logging()
    with user_errors(logger):
        args = _parse_args(argv)
        report = summarize(load_results(args.results, args.chains, args.num_chains))
        atomic_write(args.output_dir / "results.json", json.dumps(report.to_json(), indent=2))
        plot_report(report, args.output_dir / "results.png")
    logger.info("%s", format_report(report))
    logger.info("Wrote %s and %s", args.output_dir / "results.json", args.output_dir / "results.png")
    return 0
