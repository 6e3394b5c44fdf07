"""Generate a CALVIN-format play dataset in our simulation with the scripted expert (docs/calvin.md 1).

Examples::

    # 1000 tasks on the procedural desk, 2 worker processes, 10 % validation segments
    subgoalvla-generate-calvin --output /data/calvin_gen --num-tasks 1000 --seed 0 --workers 2

    # CALVIN's scene D from a calvin_env clone, then convert it like a CALVIN release
    subgoalvla-generate-calvin --output /data/calvin_gen_D --num-tasks 200 --seed 1 --scene calvin_D \\
        --assets-dir /path/to/calvin_env
    subgoalvla-convert-calvin /data/calvin_gen_D --repo-id me/calvin_gen_D --split both

The tasks are played in *segments* of ``--tasks-per-segment`` chained tasks (``calvin_play.record_segment``);
each segment is one row of ``ep_start_end_ids.npy``. Segments are generated independently (segment ``i``
seeded with ``SeedSequence([seed, i])`` and a fresh simulation), so the output depends on ``--seed`` only,
not on ``--workers``. Each finished segment is written atomically to ``OUTPUT/.segments/segment-XXXXXX``; a
rerun with the same options skips finished segments. When all exist, each split is assembled into
``OUTPUT/<split>.tmp`` (frame files hard-linked, consecutive 7-digit ids, segment table, scene_info.npy,
lang_annotations/auto_lang_ann.npy, statistics.yaml) and renamed to ``OUTPUT/<split>``.

Differences from CALVIN's releases (also in docs/data.md): no depth/tactile keys, no sentence embeddings
(``language.emb`` absent), language windows span the whole expert execution of a confirmed task (not
CALVIN's 64-frame windows), ``scene_info.npy`` is written for both splits, and the validation split is
drawn from the same scene as training.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np
from tqdm import tqdm

from lerobot_subgoalvla.calvin_vocab import TASK_NAMES, check_task_name
from lerobot_subgoalvla.cli_errors import OneLineArgumentParser, require_at_least, user_errors
from lerobot_subgoalvla.datasets_conversion.calvin_format import (
    SPLITS,
    LanguageAnnotations,
    compute_statistics,
    frame_filename,
    write_frame,
    write_language,
    write_scene_info,
    write_segments,
    write_statistics,
)
from lerobot_subgoalvla.datasets_conversion.calvin_quirks import block_order_of
from lerobot_subgoalvla.datasets_conversion.generator_options import GeneratorOptions
from lerobot_subgoalvla.datasets_conversion.output_paths import refuse_overlap
from lerobot_subgoalvla.envs.calvin.protocol import RENDERERS

logger = logging.getLogger(__name__)

SEGMENTS_DIR = ".segments"


@dataclass(frozen=True)
class SegmentJob:
    """One segment to generate (picklable for worker processes)."""

    index: int
    num_tasks: int
    options: GeneratorOptions
    directory: Path


def generate_segment(job: SegmentJob) -> int:
    """Simulate and write one segment (frames 0..F-1 + ``segment.json``) atomically; returns F."""
    from lerobot_subgoalvla.datasets_conversion.calvin_play import record_segment
    from lerobot_subgoalvla.envs.calvin.sim.simulation import CalvinSimulation

    opts = job.options
    tmp = job.directory.with_suffix(".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    rng = np.random.default_rng(np.random.SeedSequence([opts.seed, job.index]))
    sim = CalvinSimulation(
        opts.scene, opts.assets_dir, opts.static_size, opts.gripper_size, renderer=opts.renderer
    )
    try:
        slot_order = tuple(name.removeprefix("block_") for name in sim.block_names)
        if slot_order != block_order_of(opts.scene_name):
            raise ValueError(
                f"scene {opts.scene}: simulation slot order {slot_order} differs from calvin_quirks"
            )
        segment = record_segment(
            sim,
            job.num_tasks,
            rng,
            opts.max_steps_per_task,
            opts.tasks,
            opts.first_task(job.index),
            windows_from_completion=opts.windows_from_completion,
            task_weights=opts.task_weights(),
        )
    finally:
        sim.close()
    for t in range(segment.num_frames):
        write_frame(tmp, t, {key: value[t] for key, value in segment.frames.items()})
    tmp.mkdir(parents=True, exist_ok=True)
    summary = {
        "num_frames": segment.num_frames,
        "windows": segment.windows,
        "attempted": segment.attempted,
        "completed": segment.completed,
    }
    (tmp / "segment.json").write_text(json.dumps(summary))
    tmp.rename(job.directory)
    return segment.num_frames


def _segment_summary(job: SegmentJob) -> dict:
    """The ``segment.json`` that ``generate_segment`` wrote: frames, windows, attempted and done tasks."""
    return json.loads((job.directory / "segment.json").read_text())


def _assemble_split(output: Path, name: str, jobs: list[SegmentJob], opts: GeneratorOptions) -> None:
    """Hard-link the segments' frames into ``OUTPUT/<name>`` with consecutive ids and write the index
    files."""
    tmp = output / f"{name}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    rows, indx, anns, tasks, lowdim = [], [], [], [], {"robot_obs": [], "scene_obs": [], "actions": []}
    next_id, attempted, completed = 0, 0, 0
    for job in jobs:
        summary = _segment_summary(job)
        num = summary["num_frames"]
        attempted, completed = attempted + len(summary["attempted"]), completed + len(summary["completed"])
        if num == 0:
            continue
        for t in range(num):
            os.link(job.directory / frame_filename(t), tmp / frame_filename(next_id + t))
            with np.load(job.directory / frame_filename(t)) as npz:
                for key, values in lowdim.items():
                    values.append(npz[key])
        for start, end, annotation, task in summary["windows"]:
            indx.append((next_id + start, next_id + end))
            anns.append(annotation)
            tasks.append(task)
        rows.append((next_id, next_id + num - 1))
        next_id += num
    if not rows:
        raise RuntimeError(f"{name}: the expert recorded no frames; check the scene/assets and the expert")
    write_segments(tmp, np.array(rows))
    write_scene_info(tmp, {opts.scene_name: (0, next_id - 1)})
    write_language(tmp, LanguageAnnotations(np.array(indx).reshape(-1, 2), anns, tasks))
    stacked = {key: np.stack(values) for key, values in lowdim.items()}
    write_statistics(tmp, compute_statistics(stacked["robot_obs"], stacked["scene_obs"], stacked["actions"]))
    tmp.rename(output / name)
    logger.info(
        "%s: %d segments, %d frames, %d language windows (%d of %d task attempts confirmed by the oracle)",
        name,
        len(rows),
        next_id,
        len(indx),
        completed,
        attempted,
    )


def _warn_if_fewer_attempts(jobs: list[SegmentJob], opts: GeneratorOptions) -> None:
    """A segment ends early when none of ``opts.tasks`` is feasible any more (one task: after its first
    attempt); say so rather than hand back fewer demonstrations than ``--num-tasks`` without a word."""
    attempted = sum(len(_segment_summary(job)["attempted"]) for job in jobs)
    if attempted < opts.num_tasks:
        logger.warning(
            "the expert attempted %d of the %d tasks asked for: a segment ends when none of --tasks is "
            "feasible any more; pass --tasks-per-segment 1 for one attempt per segment (e.g. a single task)",
            attempted,
            opts.num_tasks,
        )


def _check_options(segments_dir: Path, opts: GeneratorOptions) -> None:
    path = segments_dir / "options.json"
    record = json.loads(json.dumps(asdict(opts)))  # tuples as JSON lists, as read back
    finished = [p for p in segments_dir.glob("segment-*") if p.suffix != ".tmp"] if path.is_file() else []
    # Options recorded by a run that finished no segment protect nothing: the corrected rerun replaces them.
    if finished and json.loads(path.read_text()) != record:
        raise ValueError(
            f"{path}: OUTPUT holds a generation with other options; rerun with them or use a new --output"
        )
    segments_dir.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=2))


#: Written into OUTPUT when a run finishes: the options that made the dataset.
OPTIONS_RECORD = "generator_options.json"


def generate(output: Path, opts: GeneratorOptions, workers: int = 1) -> dict[str, Path]:
    """Generate (or finish generating) ``OUTPUT/training`` and ``OUTPUT/validation``; returns their paths."""
    output = Path(output)
    require_at_least(1, {"--workers": workers})
    if opts.assets_dir is not None:
        refuse_overlap(output, "--output", Path(opts.assets_dir), "the calvin_env clone (--assets-dir)")
    splits = [name for name in SPLITS if name == "training" or opts.val_fraction > 0]  # no empty validation
    from lerobot_subgoalvla.envs.calvin.sim.assets import load_scene_source

    load_scene_source(opts.scene, opts.assets_dir)  # scene name and files, before anything is written
    segments_dir = output / SEGMENTS_DIR
    existing = [name for name in SPLITS if (output / name).exists()]
    if existing and not segments_dir.is_dir():  # an unfinished run of ours keeps SEGMENTS_DIR to the very end
        if (output / OPTIONS_RECORD).is_file():
            raise FileExistsError(f"{output}: already holds a generated dataset; choose another --output")
        raise FileExistsError(
            f"{output}: already has {', '.join(f'{n}/' for n in existing)} from something else; "
            "choose an empty --output"
        )
    _check_options(segments_dir, opts)
    jobs = [
        SegmentJob(i, n, opts, segments_dir / f"segment-{i:06d}") for i, n in enumerate(opts.segment_tasks())
    ]
    todo = [job for job in jobs if not job.directory.is_dir()]
    with tqdm(
        total=opts.num_tasks, initial=opts.num_tasks - sum(j.num_tasks for j in todo), unit="task"
    ) as bar:
        if workers <= 1:
            for job in todo:
                generate_segment(job)
                bar.update(job.num_tasks)
        else:
            with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
                for job, _ in zip(todo, pool.map(generate_segment, todo), strict=True):
                    bar.update(job.num_tasks)
    _warn_if_fewer_attempts(jobs, opts)
    validation = opts.validation_segments()
    for name in splits:
        selected = [job for job in jobs if (job.index in validation) == (name == "validation")]
        if not (output / name).is_dir():
            _assemble_split(output, name, selected, opts)
    (output / OPTIONS_RECORD).write_text(json.dumps(asdict(opts), indent=2))  # marks the dataset as ours
    shutil.rmtree(segments_dir)
    return {name: output / name for name in splits}


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The CLI flags (module docstring)."""
    parser = OneLineArgumentParser(
        prog="subgoalvla-generate-calvin",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--output", type=Path, required=True, help="dataset folder to create")
    parser.add_argument("--num-tasks", type=int, required=True, help="task attempts in total")
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--scene", default="procedural", help="procedural or calvin_A .. calvin_D")
    parser.add_argument("--assets-dir", default=None, help="calvin_env clone (needed for calvin_* scenes)")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--val-fraction", type=float, default=0.1)
    parser.add_argument(
        "--tasks-per-segment",
        type=int,
        default=8,
        help="task attempts in a row per start state (a segment ends early when no --tasks task is feasible)",
    )
    parser.add_argument("--max-steps-per-task", type=int, default=360)
    parser.add_argument("--static-size", type=int, default=200)
    parser.add_argument("--gripper-size", type=int, default=84)
    parser.add_argument(
        "--renderer",
        choices=RENDERERS,
        default="tiny",
        help="camera renderer: tiny (pybullet's CPU TinyRenderer) or egl (OpenGL, as CALVIN's own data)",
    )
    parser.add_argument(
        "--tasks",
        type=_task_list,
        default=TASK_NAMES,
        help="comma-separated CALVIN tasks the expert may play, e.g. open_drawer,close_drawer (default: all)",
    )
    parser.add_argument(
        "--balanced-starts",
        action="store_true",
        help="segments start with each task in turn, not a random one (more demonstrations of rarely "
        "feasible tasks such as most block tasks)",
    )
    parser.add_argument(
        "--fixture-weight",
        type=float,
        default=1.0,
        help="chance of a fixture task (drawer, slider, LED, light bulb) relative to a block task when the "
        "next task is drawn among the feasible ones; below 1 gives block tasks more demonstrations "
        "(default 1: uniform)",
    )
    parser.add_argument(
        "--windows-from-completion",
        action="store_true",
        help="a task's language window starts where the previous task's oracle first fired (the state a "
        "CALVIN chain hands to its next subtask), not where the expert starts it",
    )
    return parser.parse_args(argv)


def _task_list(text: str) -> tuple[str, ...]:
    """``--tasks a,b`` -> ("a", "b"); an unknown name is an argparse error naming the valid ones."""
    names = tuple(name.strip() for name in text.split(",") if name.strip())
    try:
        return tuple(check_task_name(name) for name in names)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from error


def main(argv: Sequence[str] | None = None) -> None:
    """Entry point of ``subgoalvla-generate-calvin``: one log line per error, non-zero exit."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger().setLevel(logging.INFO)  # LeRobot may have installed the root handler already
    with user_errors(logger, "interrupted; rerun the same command to continue where it stopped"):
        args = vars(parse_args(argv))
        output, workers = args.pop("output"), args.pop("workers")
        paths = generate(output, GeneratorOptions(**args), workers)
    logger.info("generated %s", ", ".join(str(p) for p in paths.values()))


if __name__ == "__main__":
    main()
