"""Two policies evaluated on the same start states, compared episode by episode (exact McNemar test).

Two ``lerobot-eval`` runs with the same ``--seed``, ``--eval.n_episodes`` and ``--eval.batch_size`` start
episode i of a task from the same state, so their outcomes pair up. Only the discordant episodes (solved by
one policy and not the other) say which is better; under "no difference" each is equally likely to fall
either way, so the two-sided exact p-value is that of a fair binomial over them: 4 episodes won against 0
lost is p = 0.125, 20 against 5 is p = 0.004.

Usage::

    python benchmarks/study/paired.py outputs/mt10conv/subgoalvla/eval \\
        benchmarks/study/runs/subgoalvla_mt10_v2/eval --names conv_stem recipe_2

One row per task both folders evaluated, then the total over those tasks. The pairing says nothing about
another training seed of either policy.
"""

from __future__ import annotations

import json
import logging
import math
import sys
from dataclasses import dataclass
from pathlib import Path

from lerobot_subgoalvla.cli_errors import OneLineArgumentParser, user_errors
from lerobot_subgoalvla.demo_report import episode_successes

logger = logging.getLogger("paired")


@dataclass(frozen=True)
class PairedTask:
    """One task's outcomes of policies A and B on the same episodes."""

    task: str
    episodes: int
    successes_a: int
    successes_b: int
    only_a: int
    only_b: int

    @property
    def p_value(self) -> float:
        return mcnemar_exact(self.only_a, self.only_b)


def mcnemar_exact(only_a: int, only_b: int) -> float:
    """Two-sided exact McNemar p-value: P(a split at least this uneven) for a fair coin over the discordant
    episodes (1.0 when there are none)."""
    discordant = only_a + only_b
    if discordant == 0:
        return 1.0
    tail = sum(math.comb(discordant, k) for k in range(min(only_a, only_b) + 1)) / 2**discordant
    return min(1.0, 2 * tail)


def read_successes(eval_dir: Path) -> dict[str, list[bool]]:
    """Task -> per-episode successes of every ``<task>/eval_info.json`` under ``eval_dir``."""
    if not eval_dir.is_dir():
        raise FileNotFoundError(
            f"{eval_dir}: no such evaluation folder (give a folder of <task>/eval_info.json)"
        )
    return {
        path.parent.name: episode_successes(json.loads(path.read_text()))
        for path in sorted(eval_dir.glob("*/eval_info.json"))
    }


def pair(a: dict[str, list[bool]], b: dict[str, list[bool]]) -> list[PairedTask]:
    """The tasks both evaluated, episode i of A against episode i of B."""
    rows = []
    for task in sorted(a.keys() & b.keys()):
        if len(a[task]) != len(b[task]):
            raise ValueError(
                f"{task}: {len(a[task])} episodes against {len(b[task])}; paired episodes need the same "
                "--eval.n_episodes, --seed and --eval.batch_size"
            )
        only_a = sum(x and not y for x, y in zip(a[task], b[task], strict=True))
        only_b = sum(y and not x for x, y in zip(a[task], b[task], strict=True))
        rows.append(PairedTask(task, len(a[task]), sum(a[task]), sum(b[task]), only_a, only_b))
    return rows


def total(rows: list[PairedTask]) -> PairedTask:
    """The rows summed into one (the episodes of every shared task pooled)."""
    return PairedTask(
        "all shared tasks",
        sum(r.episodes for r in rows),
        sum(r.successes_a for r in rows),
        sum(r.successes_b for r in rows),
        sum(r.only_a for r in rows),
        sum(r.only_b for r in rows),
    )


def table(rows: list[PairedTask], names: tuple[str, str]) -> str:
    a, b = names
    lines = [
        f"| task | episodes | {a} | {b} | only {a} | only {b} | exact p |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in [*rows, total(rows)]:
        lines.append(
            f"| {r.task} | {r.episodes} | {r.successes_a} | {r.successes_b} | {r.only_a} | {r.only_b} | "
            f"{r.p_value:.3g} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(message)s")
    parser = OneLineArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("eval_a", type=Path, help="evaluation folder of policy A (<task>/eval_info.json)")
    parser.add_argument("eval_b", type=Path, help="evaluation folder of policy B, same seeds")
    parser.add_argument("--names", nargs=2, default=("A", "B"), help="the two columns' names")
    with user_errors(logger):
        args = parser.parse_args(argv)
        rows = pair(read_successes(args.eval_a), read_successes(args.eval_b))
        if not rows:
            raise ValueError(f"{args.eval_a} and {args.eval_b} share no evaluated task")
        print(table(rows, tuple(args.names)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
