"""Study tables 2-3: SubgoalVLA and its ablations on multi-task data.

One dataset of the 8 fixture tasks (the demo's data), one training run per (method, seed), every fixture task
evaluated with the same episodes and seeds. Methods:

- ``subgoalvla`` (proprioceptive cross-attention, planner, both stages): the laptop preset as the demo trains
  it;
- pooling ablations (paper table 4): ``subgoalvla_mean_pool``, ``subgoalvla_max_pool``,
  ``subgoalvla_attn_pool``;
- planner ablations (table 3): ``subgoalvla_no_planner`` (w/o SP), ``subgoalvla_one_step_trace`` (w/o ST);
- ``subgoalvla_stage1_only`` (no stage II) and ``subgoalvla_t100`` (T = 100 training timesteps, DDIM 10);
- ``multi_task_dit``: LeRobot's language-conditioned diffusion transformer (CLIP vision and text towers),
  built from a random CLIP saved locally (``random_clip.py``) the size of ``laptop``'s own towers. It stacks
  its cameras before resizing them, so it needs both of one shape: it trains on ``fixtures84``, the same
  generated episodes (same seed and tasks) rendered with an 84 px static camera, and ``subgoalvla_84`` is
  SubgoalVLA on that same data (``laptop`` resizes the static camera to 80 px either way).

Usage::

    python benchmarks/study/multi_task.py --methods subgoalvla subgoalvla_mean_pool --seeds 0 1 2
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from common import (
    FIXTURE_TASKS,
    DataSpec,
    Method,
    RunSpec,
    execute,
    two_stage_flags,
)

LAPTOP = ("--policy.type=subgoalvla", "--policy.preset=laptop")
METHODS = {
    "subgoalvla": Method("subgoalvla", LAPTOP),
    "subgoalvla_mean_pool": Method("subgoalvla_mean_pool", (*LAPTOP, "--policy.feature_aggregation=mean")),
    "subgoalvla_max_pool": Method("subgoalvla_max_pool", (*LAPTOP, "--policy.feature_aggregation=max")),
    "subgoalvla_attn_pool": Method("subgoalvla_attn_pool", (*LAPTOP, "--policy.feature_aggregation=attn")),
    "subgoalvla_no_planner": Method("subgoalvla_no_planner", (*LAPTOP, "--policy.use_planner=false")),
    "subgoalvla_one_step_trace": Method(
        "subgoalvla_one_step_trace", (*LAPTOP, "--policy.subgoal_trace_len=1")
    ),
    "subgoalvla_stage1_only": Method("subgoalvla_stage1_only", LAPTOP),
    "subgoalvla_t100": Method(
        "subgoalvla_t100",
        (
            *LAPTOP,
            *(
                f"--policy.{head}.{flag}"
                for head in ("planner", "generator")
                for flag in ("num_train_timesteps=100", "num_inference_steps=10")
            ),
        ),
    ),
}
#: LeRobot's multi_task_dit at its own defaults except: the random CLIP towers (``--policy.*_encoder_name``),
#: images resized to 88 px and cropped to the towers' 80 px (its default 224 crop fits no CALVIN camera); the
#: rate of a model trained from scratch: 3e-4 for all of it, as ``laptop`` gives its own random tower and LLM
#: (its default 2e-5 with 0.1x for the vision tower assumes pretrained CLIP weights); and its transformer at
#: 256 x 4 layers instead of 512 x 6 (48 M parameters, 3-7 s per update of 32 on the loaded 2-core machine,
#: hours for the study's budget; 256 x 4 has 10 M and costs about twice ``laptop``'s update).
MULTI_TASK_DIT_FLAGS = (
    "--policy.type=multi_task_dit",
    "--policy.hidden_dim=256",
    "--policy.num_layers=4",
    "--policy.image_resize_shape=[88,88]",
    "--policy.image_crop_shape=[80,80]",
    "--policy.optimizer_lr=3e-4",
    "--policy.vision_encoder_lr_multiplier=1.0",
)
METHODS["subgoalvla_84"] = Method("subgoalvla_84", LAPTOP)
METHODS["multi_task_dit"] = Method("multi_task_dit", MULTI_TASK_DIT_FLAGS)
#: Methods trained on the 84 px copy of the fixture data (``multi_task_dit`` needs cameras of one shape).
ON_84_PX_DATA = {"multi_task_dit", "subgoalvla_84"}
#: Methods trained through both stages (stage II for the last fifth, as the demo does).
TWO_STAGE = {
    name
    for name in METHODS
    if name.startswith("subgoalvla") and name not in ("subgoalvla_no_planner", "subgoalvla_stage1_only")
}


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", nargs="+", default=["subgoalvla"], choices=list(METHODS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument(
        "--demos", type=int, default=320, help="expert task attempts in the multi-task dataset"
    )
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument(
        "--chains",
        type=int,
        default=0,
        help="also evaluate CALVIN's LH-MTLC chains 0 .. N-1 (a shorter chain evaluation is continued)",
    )
    parser.add_argument("--work-dir", type=Path, default=Path("outputs/study"))
    parser.add_argument(
        "--dataset",
        type=Path,
        default=None,
        metavar="ROOT",
        help="train on this converted fixture-task dataset (e.g. outputs/demo/dataset), not a new one",
    )
    parser.add_argument(
        "--eval-batch-size",
        type=int,
        default=1,
        help="episodes lerobot-eval steps together (async envs if > 1)",
    )
    parser.add_argument("--dry-run", action="store_true")
    args = parser.parse_args()
    data = DataSpec("fixtures", FIXTURE_TASKS, args.demos)
    data_84 = DataSpec("fixtures84", FIXTURE_TASKS, args.demos, static_size=84)
    for name in args.methods:
        extra = two_stage_flags(args.steps) if name in TWO_STAGE else ()
        if name == "multi_task_dit":
            from random_clip import save_random_clip

            clip = args.work_dir.resolve() / "random_clip"
            if not args.dry_run:
                save_random_clip(clip)
            extra = (f"--policy.vision_encoder_name={clip}", f"--policy.text_encoder_name={clip}")
        for seed in args.seeds:
            spec = RunSpec(
                METHODS[name],
                "multi_task",
                data_84 if name in ON_84_PX_DATA else data,
                FIXTURE_TASKS,
                seed,
                args.steps,
                args.episodes,
                extra,
                dataset_root=None if name in ON_84_PX_DATA else args.dataset,
                eval_batch_size=args.eval_batch_size,
                chains=args.chains,
            )
            if args.dry_run:
                print(spec.run_name, " ".join((*spec.method.policy_flags, *extra)))
                continue
            for record in execute(spec, args.work_dir):
                chains = f" avg len {record['avg_len']:.2f}" if "avg_len" in record else ""
                print(
                    f"{record['method']:>26} {record['task']:<20} seed {seed}: "
                    f"{record['successes']}/{record['episodes']}{chains}"
                )


if __name__ == "__main__":
    main()
