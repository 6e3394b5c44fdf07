"""Convert CALVIN's native dataset into LeRobotDataset v3 with subgoal traces (the data contract:
``contract/``).

Examples::

    # LANG split of task_ABC_D (one episode per language window), AV1 video, 2 worker processes
    subgoalvla-convert-calvin /data/task_ABC_D --repo-id me/calvin_abc_lang --root /data/lerobot/calvin_abc \\
        --workers 2 --verify

    # all play data of the debug dataset, both splits (-> ROOT/training and ROOT/validation), PNG frames
    subgoalvla-convert-calvin /data/calvin_debug_dataset --repo-id me/calvin_debug --root /tmp/calvin_debug \\
        --mode all --split both --image-format image

    # continue after an interruption (Ctrl-C, crash, SIGKILL): finished parts are kept
    subgoalvla-convert-calvin /data/task_ABC_D --repo-id me/calvin_abc_lang --root /data/lerobot/calvin_abc
    --resume

Output and resumption: a split is written into ``ROOT.partial/`` as fixed-size part-datasets
(``parts/part-XXXXXX``, each renamed into place only when complete), merged with LeRobot's
``aggregate_datasets``, optionally verified, and only then renamed to ``ROOT``: a folder at ``ROOT`` is
always a complete dataset. ``--resume`` keeps the finished parts (the options must match the ones recorded in
``ROOT.partial/options.json``) and returns an already complete ``ROOT`` as is; ``--overwrite`` deletes an
existing ``ROOT`` / ``ROOT.partial`` first. Without either, an existing ``ROOT`` or ``ROOT.partial`` is an
error.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from tqdm import tqdm

from lerobot_subgoalvla.cli_errors import OneLineArgumentParser, require_at_least, user_errors
from lerobot_subgoalvla.datasets_conversion.calvin_format import SPLITS, CalvinSplit
from lerobot_subgoalvla.datasets_conversion.calvin_quirks import EpisodeSpec, language_episodes, play_episodes
from lerobot_subgoalvla.datasets_conversion.calvin_validate import validate_split
from lerobot_subgoalvla.datasets_conversion.lerobot_parts import (
    ConversionOptions,
    PartJob,
    build_features,
    merge_parts,
    write_part,
)
from lerobot_subgoalvla.datasets_conversion.output_paths import (
    check_repo_id,
    check_source_folder,
    refuse_overlap,
)
from lerobot_subgoalvla.datasets_conversion.video_frames import check_video_frames

if TYPE_CHECKING:
    from lerobot.datasets import LeRobotDataset

logger = logging.getLogger(__name__)


def select_episodes(split: CalvinSplit, mode: str, max_episodes: int | None = None) -> list[EpisodeSpec]:
    """LANG: one episode per language window; ALL: one per segment (calvin_quirks has the rules)."""
    if mode == "lang":
        episodes, _ = language_episodes(split.segments, split.language())
    else:
        has_language = (split.root / "lang_annotations" / "auto_lang_ann.npy").is_file()
        episodes = play_episodes(split.segments, split.language() if has_language else None)
    return episodes if max_episodes is None else episodes[:max_episodes]


def _prepare_partial(root: Path, record: dict, resume: bool, overwrite: bool) -> Path:
    """Create or reuse ``ROOT.partial`` and check that a resumed run uses the same options."""
    partial = root.with_name(root.name + ".partial")
    if overwrite:
        shutil.rmtree(root, ignore_errors=True)
        shutil.rmtree(partial, ignore_errors=True)
    if root.exists():
        raise FileExistsError(
            f"{root}: output folder already exists; pass --overwrite or choose another --root"
        )
    options_path = partial / "options.json"
    if partial.exists():
        if not resume:
            raise FileExistsError(
                f"{partial}: an unfinished conversion is there; pass --resume to continue it or --overwrite "
                "to restart"
            )
        previous = json.loads(options_path.read_text()) if options_path.is_file() else None
        if previous != record:
            changed = sorted(k for k in record if previous is None or previous.get(k) != record[k])
            raise ValueError(
                f"{options_path}: --resume with different options ({', '.join(changed)}); "
                "rerun with the original options or pass --overwrite"
            )
    (partial / "parts").mkdir(parents=True, exist_ok=True)
    options_path.write_text(json.dumps(record, indent=2))
    return partial


def quiet_libraries() -> None:
    """Keep the libraries' chatter off the terminal: our progress bars and summary lines stay.

    LeRobot's writer logs every codec choice and aggregation step and SVT-AV1 prints a multi-line banner per
    encoded video (81 of 128 lines of a two-part conversion). Called in the main process and in each worker
    (``--verbose`` skips it). Left: LeRobot's own progress bars and FFmpeg's one-line muxer notes.
    """
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1: errors only
    logging.getLogger("lerobot").setLevel(logging.WARNING)


def _run_parts(jobs: list[PartJob], workers: int, total_frames: int, desc: str, quiet: bool = False) -> None:
    """Write the missing parts, in worker processes when ``workers > 1`` (spawned: LeRobot/torch are not
    fork-safe)."""
    todo = [job for job in jobs if not job.final_dir.is_dir()]
    done_frames = total_frames - sum(ep.length for job in todo for ep in job.episodes)
    with tqdm(total=total_frames, initial=done_frames, unit="frame", desc=desc) as progress:
        if workers <= 1:
            for job in todo:
                progress.update(write_part(job))
            return
        initializer = quiet_libraries if quiet else None
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=initializer) as pool:
            for frames in pool.map(write_part, todo):
                progress.update(frames)


def _finish(
    partial: Path, repo_id: str, jobs: list[PartJob], record: dict, options: ConversionOptions
) -> Path:
    """Merge the parts (``lerobot_parts.merge_parts``), record the trace metadata in the trace feature
    (``contract.metadata``: where LeRobot keeps it without a warning) and write the dataset card."""
    from lerobot.datasets import create_lerobot_dataset_card
    from lerobot.datasets.io_utils import load_info

    merged = partial / "dataset"
    merge_parts([job.final_dir for job in jobs], repo_id, merged)
    check_video_frames(merged)  # the merge concatenates the parts' videos
    info_path = merged / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    info["features"] = options.trace_metadata(record["split"]).attach(info["features"])
    info_path.write_text(json.dumps(info, indent=4))
    card = create_lerobot_dataset_card(
        tags=["CALVIN", "SubgoalVLA", "subgoal-traces"],
        dataset_info=load_info(merged),
        license="mit",
        url="http://calvin.cs.uni-freiburg.de",
        dataset_description=(
            f"CALVIN ({Path(record['source']).parent.name}, split {record['split']}) converted by "
            "subgoalvla-convert-calvin in "
            f"{record['mode'].upper()} mode: observation.state_history = "
            f"robot_obs[t-{record['history_length'] - 1}"
            f"..t], observation.subgoal_trace = robot_obs[t+{record['trace_start']}..t+"
            f"{record['trace_start'] + record['trace_length'] - 1}], block slots in {record['block_order']} "
            "order. "
            "CALVIN is MIT-licensed (Mees et al., 2022)."
        ),
    )
    card.save(merged / "README.md")
    return merged


def convert_split(
    split_dir: Path,
    repo_id: str,
    root: Path,
    options: ConversionOptions = ConversionOptions(),  # noqa: B008 - frozen dataclass, safe as a default
    workers: int = 1,
    episodes_per_part: int = 64,
    max_episodes: int | None = None,
    resume: bool = False,
    overwrite: bool = False,
    verify: bool = False,
    quiet: bool = False,
) -> LeRobotDataset:
    """Convert one native split into a LeRobotDataset at ``root`` (see the module docstring).

    Returns:
        The finished ``LeRobotDataset`` (read mode, pyav video backend).
    """
    from lerobot.datasets import LeRobotDataset

    _check_arguments(split_dir, root, workers, episodes_per_part, max_episodes)
    if resume and (root / "meta" / "info.json").is_file():  # finished earlier (maybe killed before clean-up)
        logger.info("%s is already complete; nothing to resume", root)
        shutil.rmtree(root.with_name(root.name + ".partial"), ignore_errors=True)
        return LeRobotDataset(repo_id, root=root, video_backend="pyav")
    split = validate_split(split_dir, require_language=options.mode == "lang")
    episodes = select_episodes(split, options.mode, max_episodes)
    if not episodes:
        raise ValueError(
            f"{split_dir}: no episodes to convert in {options.mode.upper()} mode; try --mode all"
        )
    first = split.load_frames([episodes[0].start], keys=("rgb_static", "rgb_gripper"))
    features = build_features(first["rgb_static"].shape[1:], first["rgb_gripper"].shape[1:], options)
    record = {
        **options.info(),
        "split": split.name,
        "source": str(Path(split_dir).resolve()),
        "episodes_per_part": episodes_per_part,
        "max_episodes": max_episodes,
    }
    partial = _prepare_partial(root, record, resume, overwrite)
    jobs = [
        PartJob(i // episodes_per_part, partial / "parts", repo_id, split.root,
                tuple(episodes[i : i + episodes_per_part]), features, options)
        for i in range(0, len(episodes), episodes_per_part)
    ]  # fmt: skip
    _run_parts(jobs, workers, sum(ep.length for ep in episodes), f"{split.name} ({options.mode})", quiet)
    merged = _finish(partial, repo_id, jobs, record, options)
    if verify:  # before the rename: a dataset that fails verification never appears at ROOT
        from lerobot_subgoalvla.datasets_conversion.verify_dataset import verify_dataset

        report = verify_dataset(
            LeRobotDataset(repo_id, root=merged, video_backend="pyav"), split, episodes, options
        )
        logger.info("verify: %s", report.summary())
    merged.rename(root)
    shutil.rmtree(partial)
    logger.info("wrote %d episodes / %d frames to %s", len(episodes), sum(ep.length for ep in episodes), root)
    return LeRobotDataset(repo_id, root=root, video_backend="pyav")


def _check_arguments(
    split_dir: Path, root: Path, workers: int, episodes_per_part: int, max_episodes: int | None
) -> None:
    """Everything that can be refused before a file is read or written."""
    counts = {"--workers": workers, "--episodes-per-part": episodes_per_part}
    require_at_least(1, counts if max_episodes is None else {**counts, "--max-episodes": max_episodes})
    refuse_overlap(root, "--root", Path(split_dir), "the split folder")
    refuse_overlap(
        root.with_name(root.name + ".partial"), "--root (its .partial)", Path(split_dir), "the split"
    )


def _check_push_possible() -> None:
    if os.environ.get("HF_HUB_OFFLINE", "0").lower() in ("1", "true", "yes", "on"):
        raise RuntimeError("--push-to-hub: HF_HUB_OFFLINE is set; unset HF_HUB_OFFLINE (and log in) to push")


def convert(
    src: Path,
    repo_id: str,
    root: Path | None = None,
    split: Literal["training", "validation", "both"] = "training",
    push_to_hub: bool = False,
    **kwargs,
) -> dict[str, LeRobotDataset]:
    """Convert one or both splits of a native CALVIN dataset folder.

    With ``split="both"`` the splits become two datasets, ``ROOT/training`` (repo ``ID-training``) and
    ``ROOT/validation`` (repo ``ID-validation``): LeRobot trains on one dataset per repo id, and CALVIN's
    validation split is a different scene (D) that must not leak into training. ``kwargs`` go to
    :func:`convert_split` (options as in the CLI).

    Returns:
        ``{split_name: LeRobotDataset}``.
    """
    check_repo_id(repo_id)  # before it names a folder: the default ROOT is $HF_LEROBOT_HOME/ID
    check_source_folder(Path(src), "SRC", "a CALVIN dataset folder containing training/ and/or validation/")
    if push_to_hub:
        _check_push_possible()
    from lerobot.utils.constants import HF_LEROBOT_HOME

    root = Path(root) if root is not None else HF_LEROBOT_HOME / repo_id
    names = list(SPLITS) if split == "both" else [split]
    if split not in (*SPLITS, "both"):
        raise ValueError(f"--split must be training, validation or both, got {split!r}")
    refuse_overlap(root, "--root", Path(src), "the CALVIN folder")  # before --overwrite deletes anything
    datasets = {}
    for name in names:
        target_root, target_id = (root / name, f"{repo_id}-{name}") if split == "both" else (root, repo_id)
        datasets[name] = convert_split(Path(src) / name, target_id, target_root, **kwargs)
        if push_to_hub:
            datasets[name].push_to_hub(tags=["CALVIN", "SubgoalVLA"], license="mit")
    return datasets


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The CLI flags (module docstring)."""
    parser = OneLineArgumentParser(
        prog="subgoalvla-convert-calvin",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("src", type=Path, help="CALVIN dataset folder (containing training/ and validation/)")
    parser.add_argument("--repo-id", required=True, help="dataset id, e.g. me/calvin_abc_lang")
    parser.add_argument("--root", type=Path, default=None, help="output folder (default $HF_LEROBOT_HOME/ID)")
    parser.add_argument("--push-to-hub", action="store_true", help="upload when done (needs network + login)")
    parser.add_argument("--mode", choices=("lang", "all"), default="lang")
    parser.add_argument("--split", choices=("training", "validation", "both"), default="training")
    parser.add_argument("--trace-start", type=int, default=14)
    parser.add_argument("--trace-length", type=int, default=8)
    parser.add_argument("--history-length", type=int, default=15)
    parser.add_argument("--image-format", choices=("video", "image"), default="video")
    parser.add_argument("--workers", type=int, default=1, help="worker processes writing parts in parallel")
    parser.add_argument("--episodes-per-part", type=int, default=64, help="resume granularity")
    parser.add_argument("--max-episodes", type=int, default=None, help="convert only the first N episodes")
    parser.add_argument("--verify", action="store_true", help="reload and compare with the source")
    parser.add_argument("--resume", action="store_true", help="continue ROOT.partial from an interrupted run")
    parser.add_argument("--overwrite", action="store_true", help="delete ROOT and ROOT.partial first")
    parser.add_argument(
        "--verbose", action="store_true", help="keep LeRobot's, FFmpeg's and the AV1 encoder's own log lines"
    )
    return parser.parse_args(argv)


def options_from_args(args: argparse.Namespace) -> dict:
    """``convert(**...)`` keyword arguments from the parsed flags."""
    option_fields = ConversionOptions.__dataclass_fields__
    options = ConversionOptions(**{k: v for k, v in vars(args).items() if k in option_fields})
    passthrough = ("workers", "episodes_per_part", "max_episodes", "resume", "overwrite", "verify")
    return {"options": options, "quiet": not args.verbose, **{k: getattr(args, k) for k in passthrough}}


def main(argv: Sequence[str] | None = None) -> None:
    """Entry point of ``subgoalvla-convert-calvin``: one log line per error, non-zero exit."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger().setLevel(logging.INFO)  # LeRobot may have installed the root handler already
    with user_errors(logger, "interrupted; rerun the same command with --resume to continue"):
        args = parse_args(argv)
        if not args.verbose:
            quiet_libraries()
        datasets = convert(
            args.src, args.repo_id, args.root, args.split, args.push_to_hub, **options_from_args(args)
        )
    for name, dataset in datasets.items():
        logger.info(
            "%s: %d episodes, %d frames at %s", name, dataset.num_episodes, dataset.num_frames, dataset.root
        )


if __name__ == "__main__":
    main()
