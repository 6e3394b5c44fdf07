"""Frames from the failed rollout videos of a ``lerobot-eval`` run, one row per failed episode, so that a
study's failure modes are told from pictures anyone can regenerate (``failure_frames.png`` of a kept run).

An evaluation folder holds one ``<task>/eval_info.json`` per task, as ``scripts/demo.sh`` and
``scripts/metaworld.sh`` write them; each lists its episodes' successes and video paths. Tasks are shown from
the least successful up; a task with no failed episode is left out.

Usage::

    python benchmarks/study/failure_frames.py outputs/mt10v2/subgoalvla/eval --episodes-per-task 1 \\
        --frames 6 --output benchmarks/study/runs/subgoalvla_mt10_v2/failure_frames.png
"""

from __future__ import annotations

import argparse
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class FailedEpisode:
    task: str
    episode: int
    video: Path


def _resolve_video(recorded: str, task_dir: Path) -> Path:
    """The video at ``recorded`` (the path lerobot-eval wrote, relative to where it ran) or, when the folder
    was moved since, the same file under ``task_dir``'s ``videos/``."""
    path = Path(recorded)
    if path.is_file():
        return path
    parts = path.parts
    if "videos" in parts:
        moved = task_dir.joinpath(*parts[parts.index("videos") :])
        if moved.is_file():
            return moved
    raise SystemExit(
        f"{task_dir / 'eval_info.json'}: video {recorded} is not there; was the run's videos/ kept?"
    )


def failed_episodes(eval_dir: Path, per_task: int, tasks: list[str] | None = None) -> list[FailedEpisode]:
    """Up to ``per_task`` failed episodes of every task in ``eval_dir`` (or of ``tasks``), the least
    successful task first."""
    infos = sorted(eval_dir.glob("*/eval_info.json"))
    if tasks is not None:
        infos = [eval_dir / task / "eval_info.json" for task in tasks]
        missing = [str(path) for path in infos if not path.is_file()]
        if missing:
            raise SystemExit(
                f"--tasks: no evaluation at {', '.join(missing)}; name tasks evaluated in {eval_dir}"
            )
    if not infos:
        raise SystemExit(
            f"{eval_dir}: no <task>/eval_info.json; pass the eval folder of a finished lerobot-eval run"
        )
    from lerobot_subgoalvla.demo_report import episode_successes

    by_task = []
    for info_path in infos:
        info = json.loads(info_path.read_text())
        successes, videos = episode_successes(info), info["overall"]["video_paths"]
        failed = [episode for episode, success in enumerate(successes) if not success][:per_task]
        episodes = [
            FailedEpisode(info_path.parent.name, i, _resolve_video(videos[i], info_path.parent))
            for i in failed
        ]
        by_task.append((np.mean(successes), info_path.parent.name, episodes))
    return [episode for _, _, episodes in sorted(by_task, key=lambda item: item[:2]) for episode in episodes]


def video_frames(video: Path, count: int) -> tuple[list[int], list[np.ndarray]]:
    """``count`` evenly spaced frames of ``video`` (the first and the last included) and their indices."""
    import av

    from lerobot_subgoalvla.datasets_conversion.video_frames import count_video_frames

    total = count_video_frames(video)
    indices = sorted(set(np.linspace(0, total - 1, count).round().astype(int).tolist()))
    wanted = set(indices)
    # Keep only the chosen frames: a 500-step video at 480 px is 350 MB decoded.
    with av.open(str(video)) as container:
        images = [
            f.to_ndarray(format="rgb24") for i, f in enumerate(container.decode(video=0)) if i in wanted
        ]
    return indices, images


def plot(episodes: list[FailedEpisode], frames: int, output: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from lerobot_subgoalvla.atomic_files import atomic_write

    fig = Figure(figsize=(2 * frames, 2.2 * len(episodes)), layout="tight")
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(episodes), frames, squeeze=False)
    for row, episode in zip(axes, episodes, strict=True):
        indices, images = video_frames(episode.video, frames)
        for column, ax in enumerate(row):
            ax.axis("off")
            if column < len(images):
                ax.imshow(images[column])
                ax.set_title(f"{episode.task} ep {episode.episode}: frame {indices[column]}", fontsize=6)
    atomic_write(output, lambda handle: fig.savefig(handle, format="png", dpi=110))


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("eval_dir", type=Path, help="folder with one <task>/eval_info.json per task")
    parser.add_argument("--output", type=Path, required=True, help="PNG to write")
    parser.add_argument("--episodes-per-task", type=int, default=1, help="failed episodes shown per task")
    parser.add_argument("--frames", type=int, default=6, help="frames per episode, evenly spaced")
    parser.add_argument("--tasks", nargs="+", help="only these tasks (default: every task with a failure)")
    args = parser.parse_args()
    if args.episodes_per_task < 1 or args.frames < 2:
        parser.error("--episodes-per-task must be >= 1 and --frames >= 2")
    episodes = failed_episodes(args.eval_dir, args.episodes_per_task, args.tasks)
    if not episodes:
        raise SystemExit(f"{args.eval_dir}: every episode succeeded; there is no failure to show")
    plot(episodes, args.frames, args.output)
    logger.info(
        "%d failed episodes of %d tasks -> %s", len(episodes), len({e.task for e in episodes}), args.output
    )


if __name__ == "__main__":
    main()
