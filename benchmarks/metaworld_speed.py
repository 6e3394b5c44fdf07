"""Meta-World expert generation speed: steps/s and where the time goes, per task and image size.

Records ``--episodes`` expert episodes per task (seeds 0, 1, ...) through LeRobot's Meta-World env exactly as
``subgoalvla-generate-metaworld`` does (``lerobot_subgoalvla.metaworld.record``), writes the successful ones
into a throw-away LeRobotDataset (``--image-format``), and prints medians over episodes of:

* ``steps/s``: recorded frames per wall-clock second, writing included (one process, one core);
* the share of each step spent in ``render`` (MuJoCo offscreen, Mesa EGL on a CPU), ``physics`` (Meta-World's
  step and reset), ``expert`` (the scripted policy), ``env`` (the rest: LeRobot's wrapper, copies) and
  ``write`` (``add_frame`` + ``save_episode``, encoding included);
* ``diff@80``: for sizes below 480, the mean absolute pixel difference (0-255) between this render and the
  480 render of the same state, both resized to 80 x 80 as the ``laptop`` preset does
  (``torch.nn.functional.interpolate(mode="bilinear", antialias=True)``). Same seeds give the same states at
  every size: rendering does not touch the physics.

Usage:
    MUJOCO_GL=egl OMP_NUM_THREADS=1 python benchmarks/metaworld_speed.py
    MUJOCO_GL=egl python benchmarks/metaworld_speed.py --tasks reach-v3 --sizes 480 224 --episodes 3
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812 - the usual alias

from lerobot_subgoalvla.contract.keys import SINGLE_IMAGE_KEY as IMAGE_KEY
from lerobot_subgoalvla.datasets_conversion.video_frames import encoder_options
from lerobot_subgoalvla.metaworld.generate import FPS, ROBOT_TYPE, features
from lerobot_subgoalvla.metaworld.record import Episode, MetaworldRecorder
from lerobot_subgoalvla.metaworld.tasks import task_description

PARTS = ("render", "physics", "expert", "env", "write")


def resized(images: np.ndarray, side: int = 80) -> torch.Tensor:
    """(T, S, S, 3) uint8 -> (T, 3, side, side) float in [0, 255], as the laptop preset resizes."""
    batch = torch.from_numpy(images).permute(0, 3, 1, 2).float()
    return F.interpolate(batch, size=(side, side), mode="bilinear", antialias=True, align_corners=False)


def record_and_write(task: str, size: int, seeds: list[int], image_format: str, root: Path) -> list[Episode]:
    """Record one episode per seed; write the successful ones; ``Episode.seconds["write"]`` filled in."""
    from lerobot.datasets import LeRobotDataset

    episodes = []
    with MetaworldRecorder(task, size) as recorder:
        dataset = LeRobotDataset.create(
            repo_id=f"bench/{task}-{size}", fps=FPS, features=features(size, image_format), root=root,
            robot_type=ROBOT_TYPE, use_videos=image_format == "video", video_backend="pyav",
            **encoder_options(image_format == "video", recorder.max_episode_steps + 1),
        )  # fmt: skip
        for seed in seeds:
            episode = recorder.record(seed)
            start = time.perf_counter()
            if episode.success:
                for t in range(episode.length):
                    frame = {key: value[t] for key, value in episode.frames.items()}
                    dataset.add_frame(frame | {"task": task_description(task)})
                dataset.save_episode()
            episode.seconds["write"] = time.perf_counter() - start
            episodes.append(episode)
    dataset.finalize()
    return episodes


def row(task: str, size: int, episodes: list[Episode], reference: list[Episode] | None) -> str:
    """One table line: medians over episodes."""
    per_step = [{k: v / e.length for k, v in e.seconds.items()} for e in episodes]
    totals = [sum(s.values()) for s in per_step]
    shares = {
        p: statistics.median(s[p] / total for s, total in zip(per_step, totals, strict=True)) for p in PARTS
    }
    diff = "-"
    if reference is not None:
        diffs = [
            float((resized(e.frames[IMAGE_KEY]) - resized(r.frames[IMAGE_KEY])).abs().mean())
            for e, r in zip(episodes, reference, strict=True)
            if e.length == r.length
        ]
        diff = f"{statistics.median(diffs):.2f}" if diffs else "n/a"
    lengths = [e.length for e in episodes]
    successes = sum(e.success for e in episodes)
    return (
        f"{task:<16} {size:>4} {successes:>3}/{len(episodes):<3} {statistics.median(lengths):>6.0f} "
        f"{1 / statistics.median(totals):>7.2f} {1000 * statistics.median(totals):>7.1f} "
        + " ".join(f"{100 * shares[p]:>6.1f}%" for p in PARTS)
        + f" {diff:>8}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--tasks", nargs="+", default=["reach-v3", "drawer-open-v3"])
    parser.add_argument("--sizes", nargs="+", type=int, default=[480, 224, 128])
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--image-format", choices=("video", "image"), default="video")
    args = parser.parse_args()
    os.environ.setdefault("MUJOCO_GL", "egl")
    torch.set_num_threads(1)
    sizes = [480] + [s for s in args.sizes if s != 480]  # 480 first: the reference of diff@80
    print(f"load average: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores (timings scale with contention)")
    header = (
        f"{'task':<16} {'size':>4} {'ok':>7} {'steps':>6} {'steps/s':>7} {'ms/step':>7} "
        + " ".join(f"{p:>7}" for p in PARTS)
        + f" {'diff@80':>8}"
    )
    print(header)
    print("-" * len(header))
    with tempfile.TemporaryDirectory() as tmp:
        for task in args.tasks:
            reference = None
            for size in sizes:
                root = Path(tmp) / f"{task}-{size}"
                episodes = record_and_write(task, size, list(range(args.episodes)), args.image_format, root)
                print(row(task, size, episodes, reference if size != 480 else None), flush=True)
                reference = episodes if size == 480 else reference


if __name__ == "__main__":
    main()
