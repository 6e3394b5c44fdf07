"""Study table 1: SubgoalVLA against LeRobot's ``diffusion`` and ``act`` on single-task datasets.

Diffusion Policy and ACT take no language, so every method is trained per task on a dataset of that task alone
(``subgoalvla-generate-calvin --tasks <task>``), with the same number of training samples (steps x batch) and
the same evaluation seeds. LeRobot's diffusion needs all cameras of one shape, so this table's data and env
use 84 px for both cameras (for every method alike). Nothing downloads: the ResNet-18 backbones of diffusion
and ACT start from random weights (``pretrained_backbone_weights=null``), as SubgoalVLA's laptop backbone
does.

Usage::

    python benchmarks/study/single_task.py --tasks open_drawer turn_on_led --seeds 0 1 2 --steps 3000
    python benchmarks/study/single_task.py --dry-run          # print the commands only
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from common import EVAL_SEED, FIXTURE_TASKS, DataSpec, Method, RunSpec, execute, two_stage_flags

METHODS = {
    "subgoalvla": Method("subgoalvla", ("--policy.type=subgoalvla", "--policy.preset=laptop")),
    "diffusion": Method("diffusion", ("--policy.type=diffusion", "--policy.pretrained_backbone_weights=null",
                                      "--policy.crop_shape=[76,76]", "--policy.device=cpu")),
    "act": Method("act", ("--policy.type=act", "--policy.pretrained_backbone_weights=null",
                          "--policy.chunk_size=15", "--policy.n_action_steps=8", "--policy.device=cpu")),
}  # fmt: skip


def specs(tasks: list[str], methods: list[str], seeds: list[int], steps: int, demos: int, episodes: int):
    for task in tasks:
        # one attempt per segment: with a single task, a segment ends once the task is done
        data = DataSpec(
            f"single_{task}", (task,), demos, static_size=84, gripper_size=84, tasks_per_segment=1
        )
        for seed in seeds:
            for name in methods:
                extra = two_stage_flags(steps) if name == "subgoalvla" else ()
                yield RunSpec(METHODS[name], "single_task", data, (task,), seed, steps, episodes, extra)


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(FIXTURE_TASKS), choices=FIXTURE_TASKS)
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--steps", type=int, default=3000, help="training steps (batch 32) per run")
    parser.add_argument("--demos", type=int, default=40, help="expert task attempts per single-task dataset")
    parser.add_argument(
        "--episodes", type=int, default=20, help=f"evaluation episodes (seeds {EVAL_SEED}...)"
    )
    parser.add_argument("--work-dir", type=Path, default=Path("outputs/study"))
    parser.add_argument("--dry-run", action="store_true", help="list the runs without executing them")
    args = parser.parse_args()
    for spec in specs(args.tasks, args.methods, args.seeds, args.steps, args.demos, args.episodes):
        if args.dry_run:
            print(spec.run_name, " ".join((*spec.method.policy_flags, *spec.extra_train_flags)))
            continue
        for record in execute(spec, args.work_dir):
            print(
                f"{record['method']:>12} {record['task']:<20} seed {record['seed']}: "
                f"{record['successes']}/{record['episodes']}  ({record['train_seconds']:.0f} s training)"
            )


if __name__ == "__main__":
    main()
