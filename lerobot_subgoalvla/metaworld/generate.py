"""``subgoalvla-generate-metaworld``: Meta-World expert demos as a LeRobotDataset v3 (docs/metaworld.md).

Examples::

    # MT10, 50 successful episodes per task, one worker per core
    subgoalvla-generate-metaworld --output-root /data/mw_mt10 --repo-id me/metaworld_mt10 --tasks mt10 \\
        --episodes-per-task 50 --seed 0 --workers 2
    lerobot-train --policy.type=subgoalvla --dataset.repo_id=me/metaworld_mt10 --dataset.root=/data/mw_mt10 \\
        --env.type=metaworld --env.task=drawer-open-v3 ...

Meta-World's scripted expert plays each task inside LeRobot's own Meta-World env (``record.py``), from
Meta-World's randomised start states, one env seed per attempt. Only successful episodes are kept; an episode
ends at the first success (that frame included) or at ``--max-steps`` (default: the env's 500). The written
features, dtypes, fps (80) and ``task`` strings are those of LeRobot's published ``lerobot/metaworld_mt50``:
``observation.image`` (S, S, 3), ``observation.state`` (4), ``observation.environment_state`` (39:
Meta-World's full observation), ``action`` (4), ``next.reward``, ``next.success``, ``task_id``; ``task`` is
LeRobot's instruction for the task (``"Open a drawer"``). Images are stored as video by default
(``--image-format image``: PNG frames, as the published dataset); both load the same in ``lerobot-train``.

Determinism and parallelism: each task's episodes are split into parts of ``--episodes-per-part``; part ``p``
of task ``k`` tries env seeds drawn from ``SeedSequence([seed, task_id, p, attempt])``, so the dataset depends
on the options only, not on ``--workers``. Parts are complete LeRobotDatasets written by worker processes
(one fresh process per part, which also gives each part its own EGL context) into ``DIR.partial/parts`` and
renamed when finalized (``--workers 1``: in this process, one part after another);
``lerobot.datasets.aggregate.aggregate_datasets`` merges them, and the merged dataset
is renamed to ``DIR`` at the very end. An interrupted run resumes: rerun the same command.

``--action-noise`` (default 0): std of Gaussian noise added to the executed action, while the recorded label
stays the expert's action (DART-style: the policy learns recoveries from slightly perturbed states). Zero by
default because the published dataset is noise-free, Meta-World's randomised starts already vary every
episode, and noise can cost the expert success on precise tasks (not measured here).

``--image-size`` (default 480, LeRobot's env and the published data): after the ``laptop`` preset's resize to
80 x 80 (bilinear, antialias) a smaller render differs little from a 480 one of the same state (mean abs
difference 0.50/255 from 224 px, 1.1/255 from 128 px), but it is only 1.37x faster at 224 px (Mesa's CPU
rasteriser has a large per-frame cost; ``benchmarks/metaworld_speed.py``), and the stored shape would no
longer be the published one nor what ``lerobot-eval`` delivers; so 480 stays the default and 224 is an opt-in
speed-up for policies that resize their inputs.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import statistics
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np
from tqdm import tqdm

from lerobot_subgoalvla.cli_errors import OneLineArgumentParser, require_at_least, user_errors
from lerobot_subgoalvla.contract.keys import ACTION_KEY, ENV_STATE_KEY, SINGLE_IMAGE_KEY, STATE_KEY
from lerobot_subgoalvla.datasets_conversion.video_frames import check_video_frames, encoder_options
from lerobot_subgoalvla.metaworld.tasks import parse_tasks, require_metaworld, task_description, task_id

logger = logging.getLogger(__name__)

FPS = 80  # LeRobot's Meta-World env (metadata["render_fps"]) and the published dataset
ROBOT_TYPE = "metaworld"
IMAGE_FORMATS = ("video", "image")
SUMMARY_FILE = "generation.json"  # in each part; all of them end up in DIR/meta/metaworld_generation.json


@dataclass(frozen=True)
class GenerateOptions:
    """Everything that determines the generated data (kept in ``DIR.partial/options.json`` to resume)."""

    tasks: tuple[str, ...]
    episodes_per_task: int
    seed: int
    image_size: int = 480
    action_noise: float = 0.0
    image_format: str = "video"
    max_steps: int | None = None
    episodes_per_part: int = 10
    max_tries_factor: int = 4

    def __post_init__(self) -> None:
        if not self.tasks:
            raise ValueError("--tasks needs at least one Meta-World task name or set (e.g. reach-v3 or mt10)")
        counts = {
            "--episodes-per-task": self.episodes_per_task,
            "--episodes-per-part": self.episodes_per_part,
            "--max-tries-factor": self.max_tries_factor,
        }
        require_at_least(1, counts)
        require_at_least(0, {"--seed": self.seed})  # numpy's SeedSequence takes non-negative entropy only
        if self.max_steps is not None:
            require_at_least(1, {"--max-steps": self.max_steps})
        require_at_least(32, {"--image-size": self.image_size})
        if self.image_size > 480:  # Meta-World's offscreen buffer is 480 x 480
            raise ValueError(
                f"--image-size must be <= 480 (Meta-World's render buffer), got {self.image_size}"
            )
        if not 0.0 <= self.action_noise <= 1.0:
            raise ValueError(
                f"--action-noise must be in [0, 1] (actions lie in [-1, 1]), got {self.action_noise}"
            )
        if self.image_format not in IMAGE_FORMATS:
            raise ValueError(f"--image-format must be video or image, got {self.image_format!r}")


@dataclass(frozen=True)
class PartJob:
    """One part-dataset: ``episodes`` successful episodes of one task (picklable for worker processes)."""

    task: str
    index: int
    episodes: int
    directory: Path
    repo_id: str
    options: GenerateOptions


def features(image_size: int, image_format: str) -> dict[str, dict]:
    """The published ``lerobot/metaworld_mt50`` schema (names as published; images height-width-channels)."""
    return {
        SINGLE_IMAGE_KEY: {"dtype": image_format, "shape": (image_size, image_size, 3),
                           "names": ["height", "width", "channels"]},
        STATE_KEY: {"dtype": "float32", "shape": (4,), "names": {"axes": None}},
        ENV_STATE_KEY: {"dtype": "float32", "shape": (39,), "names": ["keypoints"]},
        ACTION_KEY: {"dtype": "float32", "shape": (4,), "names": {"axes": ["x", "y", "z", "gripper"]}},
        "next.reward": {"dtype": "float32", "shape": (1,), "names": None},
        "next.success": {"dtype": "bool", "shape": (1,), "names": None},
        "task_id": {"dtype": "int16", "shape": (1,), "names": None},
    }  # fmt: skip


def attempt_seeds(seed: int, task: str, part: int, attempt: int) -> tuple[int, np.random.Generator]:
    """The env seed of one attempt and the generator of its action noise, from the options alone."""
    sequence = np.random.SeedSequence([seed, task_id(task), part, attempt])
    env_seed, noise_seed = sequence.generate_state(2, dtype=np.uint32)
    return int(env_seed), np.random.default_rng(int(noise_seed))


def plan_parts(opts: GenerateOptions, parts_dir: Path, repo_id: str) -> list[PartJob]:
    """Each task's episodes in parts of ``episodes_per_part`` (the last takes the remainder), task order."""
    jobs = []
    for position, task in enumerate(opts.tasks):
        full, rest = divmod(opts.episodes_per_task, opts.episodes_per_part)
        sizes = [opts.episodes_per_part] * full + ([rest] if rest else [])
        for index, size in enumerate(sizes):
            directory = parts_dir / f"part-{position:03d}-{index:04d}"
            jobs.append(PartJob(task, index, size, directory, repo_id, opts))
    return jobs


def record_part(job: PartJob) -> dict:
    """Record one part (in a worker process) into ``DIR.tmp``, rename it to ``DIR``; returns its summary."""
    from lerobot_subgoalvla.metaworld.record import MetaworldRecorder

    opts, tmp = job.options, job.directory.with_suffix(".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    summary = {"task": job.task, "part": job.index, "tries": 0, "lengths": [], "seconds": {}}
    description, max_tries = task_description(job.task), job.episodes * opts.max_tries_factor
    with MetaworldRecorder(job.task, opts.image_size) as recorder:
        dataset = _create_part_dataset(job, tmp, recorder.max_episode_steps)
        while len(summary["lengths"]) < job.episodes:
            if summary["tries"] >= max_tries:
                raise RuntimeError(
                    f"{job.task}: the expert succeeded in {len(summary['lengths'])} of {max_tries} tries "
                    f"(part {job.index}); lower --action-noise, raise --max-steps or --max-tries-factor"
                )
            env_seed, rng = attempt_seeds(opts.seed, job.task, job.index, summary["tries"])
            episode = recorder.record(env_seed, opts.max_steps, opts.action_noise, rng)
            summary["tries"] += 1
            _add_seconds(summary["seconds"], episode.seconds)
            if episode.success:
                start = time.perf_counter()
                _write_episode(dataset, episode.frames, description)
                _add_seconds(summary["seconds"], {"write": time.perf_counter() - start})
                summary["lengths"].append(episode.length)
    start = time.perf_counter()
    dataset.finalize()
    check_video_frames(tmp)  # a part with a dropped frame is never renamed into place
    _add_seconds(summary["seconds"], {"write": time.perf_counter() - start})
    (tmp / SUMMARY_FILE).write_text(json.dumps(summary))
    tmp.rename(job.directory)
    return summary


def _create_part_dataset(job: PartJob, root: Path, max_episode_steps: int) -> object:
    """The part's empty LeRobotDataset; videos are encoded while recording (no pass at ``save_episode``),
    with room in the encoder's queue for a whole episode, so no frame is ever dropped (``video_frames``)."""
    from lerobot.datasets import LeRobotDataset

    opts = job.options
    video = opts.image_format == "video"
    encoding = encoder_options(video, max_episode_steps + 1)  # + 1: the frame of the final state
    return LeRobotDataset.create(
        repo_id=f"{job.repo_id}-{job.directory.name}",
        fps=FPS,
        features=features(opts.image_size, opts.image_format),
        root=root,
        robot_type=ROBOT_TYPE,
        use_videos=video,
        video_backend="pyav",  # decoding backend; avoids probing torchcodec, which needs system FFmpeg
        image_writer_threads=0 if encoding["streaming_encoding"] else 2,  # PNG writing off the main thread
        **encoding,
    )


def _write_episode(dataset: object, frames: dict[str, np.ndarray], description: str) -> None:
    """``add_frame`` each of the episode's T frames, then ``save_episode``."""
    for t in range(len(frames["action"])):
        dataset.add_frame({key: value[t] for key, value in frames.items()} | {"task": description})
    dataset.save_episode()


def _add_seconds(total: dict[str, float], more: dict[str, float]) -> None:
    for key, value in more.items():
        total[key] = total.get(key, 0.0) + value


def _check_options(work_dir: Path, opts: GenerateOptions, repo_id: str) -> None:
    """Refuse to resume a run made with other options; record the options of this one."""
    path = work_dir / "options.json"
    record = json.loads(json.dumps({**asdict(opts), "repo_id": repo_id}))  # tuples as JSON lists
    if path.is_file() and json.loads(path.read_text()) != record:
        raise ValueError(
            f"{work_dir} holds an unfinished generation with other options; rerun it with the same "
            f"options to finish it, or delete {work_dir}"
        )
    work_dir.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=2))


def _run_parts(todo: list[PartJob], workers: int, total: int, done: int) -> None:
    """Record the missing parts: in this process with one worker, else one fresh process per part.

    One worker records in-process (a spawned process would spend ~15 s importing LeRobot again); the
    recorder frees its EGL context after each part, so parts in a row do not share GL state.
    """
    with tqdm(total=total, initial=done, unit="episode", desc="Meta-World expert") as bar:
        if workers == 1:
            for job in todo:
                bar.update(len(record_part(job)["lengths"]))
            return
        context = get_context("spawn")  # no fork: LeRobot and MuJoCo state must not be shared
        with ProcessPoolExecutor(workers, mp_context=context, max_tasks_per_child=1) as pool:
            futures = [pool.submit(record_part, job) for job in todo]
            for future in as_completed(futures):
                summary = future.result()  # a worker's exception stops the run here (finished parts stay)
                bar.update(len(summary["lengths"]))


def merge_parts(jobs: list[PartJob], repo_id: str, merged: Path) -> None:
    """Merge the finished parts, in task-then-part order, with LeRobot's ``aggregate_datasets``."""
    from lerobot.datasets.aggregate import aggregate_datasets

    shutil.rmtree(merged, ignore_errors=True)
    aggregate_datasets(
        repo_ids=[f"{repo_id}-{job.directory.name}" for job in jobs],
        roots=[job.directory for job in jobs],
        aggr_repo_id=repo_id,
        aggr_root=merged,
    )
    summaries = [json.loads((job.directory / SUMMARY_FILE).read_text()) for job in jobs]
    (merged / "meta" / "metaworld_generation.json").write_text(json.dumps(summaries, indent=1))


def _refuse_existing(output_root: Path) -> None:
    if output_root.exists() and (not output_root.is_dir() or any(output_root.iterdir())):
        raise FileExistsError(f"{output_root} already exists and is not empty; choose a new --output-root")


def generate(output_root: Path, repo_id: str, opts: GenerateOptions, workers: int = 1) -> Path:
    """Generate (or finish generating) the dataset at ``output_root``; returns it."""
    output_root = Path(output_root).absolute()
    require_at_least(1, {"--workers": workers})
    if not repo_id or any(c.isspace() for c in repo_id):
        raise ValueError(f"--repo-id must be a name like me/metaworld_mt10, got {repo_id!r}")
    _refuse_existing(output_root)
    require_metaworld()
    work_dir = output_root.with_name(output_root.name + ".partial")
    _check_options(work_dir, opts, repo_id)
    jobs = plan_parts(opts, work_dir / "parts", repo_id)
    todo = [job for job in jobs if not job.directory.is_dir()]
    done = sum(job.episodes for job in jobs if job not in todo)
    start = time.perf_counter()
    if todo:
        _run_parts(todo, min(workers, len(todo)), opts.episodes_per_task * len(opts.tasks), done)
    merge_parts(jobs, repo_id, work_dir / "merged")
    if output_root.is_dir():
        output_root.rmdir()  # empty (checked above); the rename needs the name free
    os.replace(work_dir / "merged", output_root)
    shutil.rmtree(work_dir)
    _log_summary(output_root, time.perf_counter() - start)
    return output_root


def _log_summary(output_root: Path, seconds: float) -> None:
    """Per task: tries, kept episodes and lengths; overall: recorded steps per second."""
    summaries = json.loads((output_root / "meta" / "metaworld_generation.json").read_text())
    per_task: dict[str, dict] = {}
    for summary in summaries:
        entry = per_task.setdefault(summary["task"], {"tries": 0, "lengths": []})
        entry["tries"] += summary["tries"]
        entry["lengths"] += summary["lengths"]
    for task, entry in per_task.items():
        lengths = entry["lengths"]
        logger.info(
            "%s: %d episodes kept of %d tries; %d-%d steps (median %d)", task, len(lengths), entry["tries"],
            min(lengths), max(lengths), statistics.median(lengths),
        )  # fmt: skip
    frames = sum(sum(entry["lengths"]) for entry in per_task.values())
    logger.info("%d frames in %.0f s (this run; %.2f frames/s)", frames, seconds, frames / max(seconds, 1e-9))


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The CLI flags (module docstring)."""
    parser = OneLineArgumentParser(
        prog="subgoalvla-generate-metaworld", description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    parser.add_argument(
        "--output-root", type=Path, required=True, help="dataset root to create (new or empty)"
    )
    parser.add_argument("--repo-id", required=True, help="dataset name, e.g. me/metaworld_mt10")
    parser.add_argument(
        "--tasks",
        type=_task_list,
        required=True,
        help="comma-separated Meta-World tasks (drawer-open-v3,reach-v3) or a set: mt10",
    )
    parser.add_argument("--episodes-per-task", type=int, required=True, help="successful episodes per task")
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--workers", type=int, default=1, help="worker processes (one per core)")
    parser.add_argument("--image-size", type=int, default=480, help="rendered side (LeRobot's env: 480)")
    parser.add_argument("--action-noise", type=float, default=0.0, help="std of executed-action noise")
    parser.add_argument("--image-format", choices=IMAGE_FORMATS, default="video")
    parser.add_argument("--max-steps", type=int, default=None, help="step cap per episode (default: 500)")
    parser.add_argument("--episodes-per-part", type=int, default=10, help="episodes per resumable unit")
    parser.add_argument("--max-tries-factor", type=int, default=4,
                        help="a part fails after this many tries per episode it needs")  # fmt: skip
    return parser.parse_args(argv)


def _task_list(text: str) -> tuple[str, ...]:
    """``--tasks`` -> names; an unknown one is an argparse error naming the closest valid ones."""
    try:
        return parse_tasks(text)
    except (ValueError, RuntimeError) as error:
        raise argparse.ArgumentTypeError(str(error)) from error


def main(argv: Sequence[str] | None = None) -> None:
    """Entry point of ``subgoalvla-generate-metaworld``: one log line per error, non-zero exit."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger().setLevel(logging.INFO)  # LeRobot may have installed the root handler already
    with user_errors(logger, "interrupted; rerun the same command to continue where it stopped"):
        args = vars(parse_args(argv))
        output_root, repo_id, workers = args.pop("output_root"), args.pop("repo_id"), args.pop("workers")
        path = generate(output_root, repo_id, GenerateOptions(**args), workers)
    logger.info("wrote %s (lerobot-train --dataset.repo_id=%s --dataset.root=%s)", path, repo_id, path)


if __name__ == "__main__":
    main()
