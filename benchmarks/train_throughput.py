"""Training throughput of ``lerobot-train``: our presets beside LeRobot's diffusion and ACT, same data and
machine.

Runs ``lerobot-train`` for ``--steps`` steps per policy on one dataset (every policy in a fresh process, one
after the other, nothing else started by the benchmark) and reads LeRobot's own log lines: ``updt_s``
(forward, backward, optimizer step) and ``data_s`` (time the loop waited for the next batch). The first logged
interval (start-up, first batches) is dropped; the table gives medians over the rest, and samples/s = batch /
(updt_s + data_s).

Usage::

    python benchmarks/train_throughput.py --dataset-root outputs/demo/dataset --repo-id local/calvin_demo
    python benchmarks/train_throughput.py ... --policies tiny laptop --threads 1 2 --workers 0 1 2
    python benchmarks/train_throughput.py --dataset-root outputs/metaworld/dataset --repo-id local/metaworld \
        --policies laptop160 laptop160_conv   # the vision stem's cost at Meta-World's recipe
    python benchmarks/train_throughput.py --dataset-root outputs/all34/dataset --repo-id local/calvin_demo \
        --policies all34 all34_separate       # one image per camera against side by side (CALVIN)

The dataset needs cameras of one shape for ``diffusion`` and ``multi_task_dit`` (LeRobot's requirement); they
are skipped otherwise. ``multi_task_dit`` is configured as in the study (``study/multi_task.py``: a random
CLIP saved to a temporary folder, nothing downloads).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent / "study"))
from lerobot_subgoalvla.demo_report import parse_train_log  # noqa: E402

METAWORLD_RECIPE = [
    "--policy.backbone.image_size=160",
    "--policy.backbone.patch_size=20",
    "--policy.n_action_steps=4",
]
CALVIN_ALL34_RECIPE = ["--policy.backbone.image_size=160", "--policy.backbone.patch_size=20"]
POLICIES = {
    "tiny": ["--policy.type=subgoalvla", "--policy.preset=tiny"],
    "laptop": ["--policy.type=subgoalvla", "--policy.preset=laptop"],
    # Meta-World's recipe 2 (scripts/metaworld.sh), CLIP's patch embedding or the convolutional stem
    "laptop160": ["--policy.type=subgoalvla", "--policy.preset=laptop", *METAWORLD_RECIPE],
    "laptop160_conv": [
        "--policy.type=subgoalvla",
        "--policy.preset=laptop",
        *METAWORLD_RECIPE,
        "--policy.backbone.vision_stem=conv",
    ],
    # CALVIN's all34 recipe (scripts/demo.sh), the paper's side-by-side cameras or one image per camera
    "all34": ["--policy.type=subgoalvla", "--policy.preset=laptop", *CALVIN_ALL34_RECIPE],
    "all34_separate": [
        "--policy.type=subgoalvla",
        "--policy.preset=laptop",
        *CALVIN_ALL34_RECIPE,
        "--policy.backbone.camera_layout=separate",
    ],
    "diffusion": [
        "--policy.type=diffusion",
        "--policy.pretrained_backbone_weights=null",
        "--policy.crop_shape=null",
    ],
    "act": ["--policy.type=act", "--policy.pretrained_backbone_weights=null"],
    "multi_task_dit": [],  # the study's flags plus the random CLIP's folder (_policy_flags)
}
SAME_SHAPE_CAMERAS = ("diffusion", "multi_task_dit")


def _policy_flags(policy: str, scratch: Path) -> list[str]:
    if policy != "multi_task_dit":
        return POLICIES[policy]
    from multi_task import MULTI_TASK_DIT_FLAGS
    from random_clip import save_random_clip

    clip = save_random_clip(scratch / "random_clip")
    return [
        *MULTI_TASK_DIT_FLAGS,
        f"--policy.vision_encoder_name={clip}",
        f"--policy.text_encoder_name={clip}",
    ]


def cameras_share_a_shape(root: Path) -> bool:
    features = json.loads((root / "meta" / "info.json").read_text())["features"]
    shapes = {tuple(f["shape"]) for f in features.values() if f["dtype"] in ("video", "image")}
    return len(shapes) == 1


def measure(
    policy: str, root: Path, repo_id: str, steps: int, batch: int, threads: int, workers: int, backend: str
) -> dict:
    with tempfile.TemporaryDirectory() as out:
        log = Path(out) / "train.log"
        command = [
            "lerobot-train",
            *_policy_flags(policy, Path(out)),
            "--policy.push_to_hub=false",
            "--policy.device=cpu",
            f"--dataset.repo_id={repo_id}",
            f"--dataset.root={root}",
            f"--dataset.video_backend={backend}",
            f"--output_dir={Path(out) / 'run'}",
            f"--steps={steps}",
            f"--batch_size={batch}",
            f"--num_workers={workers}",
            f"--log_freq={max(1, steps // 6)}",
            f"--save_freq={10 * steps}",
            "--save_checkpoint=false",
            "--wandb.enable=false",
        ]
        env = {
            **os.environ,
            "OMP_NUM_THREADS": str(threads),
            "MKL_NUM_THREADS": str(threads),
            "HF_HUB_OFFLINE": "1",
        }
        with log.open("w") as handle:
            code = subprocess.call(command, stdout=handle, stderr=subprocess.STDOUT, env=env)
        records = parse_train_log(log)[1:]
        if code != 0 or not records:
            tail = log.read_text(errors="replace").splitlines()[-3:]
            return {"policy": policy, "error": " | ".join(tail)}
    update = statistics.median(r["updt_s"] for r in records)
    data = statistics.median(r["data_s"] for r in records)
    return {
        "policy": policy,
        "threads": threads,
        "workers": workers,
        "backend": backend,
        "batch": batch,
        "updt_s": update,
        "data_s": data,
        "samples_per_s": batch / (update + data),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset-root", type=Path, required=True)
    parser.add_argument("--repo-id", required=True)
    parser.add_argument("--policies", nargs="+", default=list(POLICIES), choices=list(POLICIES))
    parser.add_argument("--steps", type=int, default=120)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--threads", nargs="+", type=int, default=[1])
    parser.add_argument("--workers", nargs="+", type=int, default=[1])
    parser.add_argument(
        "--video-backends", nargs="+", default=["pyav"], choices=["pyav", "torchcodec"],
        help="LeRobot's video decoders to compare (torchcodec needs FFmpeg's shared libraries)",
    )  # fmt: skip
    args = parser.parse_args()
    same_shape = cameras_share_a_shape(args.dataset_root)
    print(
        f"{'policy':<14} {'threads':>7} {'workers':>7} {'decoder':>10} {'batch':>5} {'updt_s':>7} "
        f"{'data_s':>7} "
        f"{'samples/s':>9}"
    )
    for policy in args.policies:
        if policy in SAME_SHAPE_CAMERAS and not same_shape:
            print(f"{policy:<14} skipped: LeRobot's {policy} needs all cameras of one shape")
            continue
        settings = itertools.product(args.threads, args.workers, args.video_backends)
        for threads, workers, backend in settings:
            run = (args.dataset_root, args.repo_id, args.steps, args.batch_size)
            r = measure(policy, *run, threads, workers, backend)
            if "error" in r:
                print(f"{policy:<14} failed: {r['error']}")
                continue
            print(
                f"{policy:<14} {threads:>7} {workers:>7} {backend:>10} {r['batch']:>5} {r['updt_s']:>7.3f} "
                f"{r['data_s']:>7.3f} {r['samples_per_s']:>9.1f}"
            )


if __name__ == "__main__":
    main()
