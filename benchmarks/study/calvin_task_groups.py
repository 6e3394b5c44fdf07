"""``--group`` flags for ``open_loop_error.py`` from a converted CALVIN dataset: episodes by task family.

Play data interleaves CALVIN's tasks, so a task's episodes are scattered; each episode carries one of CALVIN's
training instructions, which names its task (``calvin_vocab.TRAINING_ANNOTATIONS``). An instruction that
several tasks share ("lift the red block up": from the table, the slider or the drawer) is kept only where all
of them are in one family. Prints one line: ``--group FAMILY=A,B,...`` for each family with episodes, the
first ``--per-group`` episodes of each in dataset order.

    python benchmarks/study/calvin_task_groups.py outputs/all34x2/dataset --per-group 30
"""

from __future__ import annotations

import collections
import logging
import sys
from pathlib import Path

from lerobot_subgoalvla.calvin_vocab import TRAINING_ANNOTATIONS
from lerobot_subgoalvla.cli_errors import OneLineArgumentParser, user_errors

logger = logging.getLogger(__name__)

#: Family name -> test on a task name; the first family that matches takes the task.
FAMILIES = {
    "push": lambda task: task.startswith("push_") and task.endswith(("_left", "_right")) and "block" in task,
    "lift": lambda task: task.startswith("lift_"),
    "rotate": lambda task: task.startswith("rotate_"),
    "drawer": lambda task: task == "open_drawer",
}


def family_of(instruction: str, tasks_of: dict[str, set[str]]) -> str | None:
    """The family every task with this instruction belongs to, or None (unknown, or families differ)."""
    families = {
        next((name for name, test in FAMILIES.items() if test(task)), None)
        for task in tasks_of.get(instruction, ())
    }
    return families.pop() if len(families) == 1 else None


def task_groups(episode_instructions: list[tuple[int, str]], per_group: int) -> dict[str, list[int]]:
    """Family -> its first ``per_group`` episodes, from (episode index, instruction) pairs."""
    tasks_of: dict[str, set[str]] = collections.defaultdict(set)
    for task, instructions in TRAINING_ANNOTATIONS.items():
        for instruction in instructions:
            tasks_of[instruction].add(task)
    groups: dict[str, list[int]] = {name: [] for name in FAMILIES}
    for episode, instruction in sorted(episode_instructions):
        family = family_of(instruction, tasks_of)
        if family is not None and len(groups[family]) < per_group:
            groups[family].append(episode)
    return {name: episodes for name, episodes in groups.items() if episodes}


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    parser = OneLineArgumentParser(prog="calvin_task_groups.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset_root", type=Path, help="a LeRobotDataset converted from CALVIN's format")
    parser.add_argument("--per-group", type=int, default=30, help="episodes per family (the first ones)")
    with user_errors(logger):
        args = parser.parse_args(argv)
        import pandas as pd

        files = sorted((args.dataset_root / "meta" / "episodes").glob("*/*.parquet"))
        if not files:
            raise ValueError(f"{args.dataset_root}: no meta/episodes/*/*.parquet; pass a LeRobotDataset root")
        table = pd.concat([pd.read_parquet(f, columns=["episode_index", "tasks"]) for f in files])
        pairs = [(int(e), tasks[0]) for e, tasks in zip(table["episode_index"], table["tasks"], strict=True)]
        groups = task_groups(pairs, args.per_group)
        print(" ".join(f"--group {name}={','.join(map(str, eps))}" for name, eps in groups.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
