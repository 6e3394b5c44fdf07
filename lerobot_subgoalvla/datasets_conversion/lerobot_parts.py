"""Writing CALVIN episodes into LeRobotDataset v3 part-datasets (the data contract: ``contract/``).

The converter shards its episode list into fixed-size *parts*; each part is a complete LeRobotDataset
written with LeRobot's own protocol (``create`` -> ``add_frame`` -> ``save_episode`` -> ``finalize``) into
``part-XXXXXX.tmp`` and renamed to ``part-XXXXXX`` once finalized. A rename is atomic, so after a crash a
part is either complete or discarded, which makes the conversion resumable and lets parts be written by
parallel worker processes; ``lerobot.datasets.aggregate_datasets`` then merges them in order.

Dimension legend:
    F    frames of one episode
    h    history states, M trace states, p = 15 robot_obs dims
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal
from unittest import mock

import numpy as np
import pandas as pd

from lerobot_subgoalvla.calvin_vocab import (
    ACTION_NAMES,
    CALVIN_FPS,
    EVAL_INSTRUCTIONS,
    ROBOT_OBS_NAMES,
    SCENE_OBS_NAMES,
)
from lerobot_subgoalvla.contract import calvin
from lerobot_subgoalvla.contract.keys import (
    ACTION_KEY,
    ENV_STATE_KEY,
    STATE_HISTORY_KEY,
    STATE_KEY,
    SUBGOAL_TRACE_KEY,
    TASK_KEY,
)
from lerobot_subgoalvla.contract.metadata import ProprioMetadata
from lerobot_subgoalvla.contract.window import (
    PAPER_HISTORY_LENGTH,
    PAPER_TRACE_LENGTH,
    PAPER_TRACE_START,
    TraceWindow,
)
from lerobot_subgoalvla.datasets_conversion.calvin_format import CalvinSplit
from lerobot_subgoalvla.datasets_conversion.calvin_quirks import (
    CANONICAL_BLOCK_ORDER,
    EpisodeSpec,
    block_order_of,
    canonicalize_scene_obs,
)
from lerobot_subgoalvla.datasets_conversion.video_frames import check_video_frames, encoder_options


@dataclass(frozen=True)
class ConversionOptions:
    """Options that change the written data; the trace metadata records them (``trace_metadata``).

    Args:
        trace_start: offset of the first subgoal-trace state (paper appendix A: 14).
        trace_length: number of trace states (paper: 8).
        history_length: number of states in ``observation.state_history`` (15 = robot_obs[t-14 .. t]).
        image_format: ``video`` (AV1 mp4 via PyAV, LeRobot's default encoder) or ``image`` (PNG in parquet).
        mode: ``lang`` (one episode per language window) or ``all`` (one per play segment).
    """

    trace_start: int = PAPER_TRACE_START
    trace_length: int = PAPER_TRACE_LENGTH
    history_length: int = PAPER_HISTORY_LENGTH
    image_format: Literal["video", "image"] = "video"
    mode: Literal["lang", "all"] = "lang"

    def __post_init__(self) -> None:
        if self.image_format not in ("video", "image"):
            raise ValueError(f"--image-format must be 'video' or 'image', got {self.image_format!r}")
        if self.mode not in ("lang", "all"):
            raise ValueError(f"--mode must be 'lang' or 'all', got {self.mode!r}")
        for name in ("trace_length", "history_length"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        if self.trace_start < 0:
            raise ValueError(f"--trace-start must be >= 0, got {self.trace_start}")

    def info(self) -> dict:
        """The options as a JSON record (a resumed conversion must use the same)."""
        return {**asdict(self), "block_order": list(CANONICAL_BLOCK_ORDER), "source_fps": CALVIN_FPS}

    @property
    def window(self) -> TraceWindow:
        """CALVIN's window: consecutive 30 Hz frames (stride 1)."""
        return TraceWindow(self.history_length, self.trace_start, self.trace_length)

    def trace_metadata(self, split: str) -> ProprioMetadata:
        """What the trace feature records (``contract.metadata``): the window, CALVIN's angles, its evaluation
        instructions (their phrasing differs from the training annotations) and the conversion options."""
        return ProprioMetadata(
            self.window,
            CALVIN_FPS,
            calvin.ANGLE_DIMS,
            calvin.ANGLE_HOME,
            tuple(EVAL_INSTRUCTIONS.values()),
            "subgoalvla-convert-calvin",
            {"split": split, "mode": self.mode, "block_order": list(CANONICAL_BLOCK_ORDER)},
        )


def build_features(
    static_shape: tuple[int, ...], gripper_shape: tuple[int, ...], options: ConversionOptions
) -> dict[str, dict]:
    """The LeRobot feature schema of the data contract (camera sizes are read from the source frames)."""
    image_dtype = options.image_format
    hwc = ["height", "width", "channels"]
    state_dim = len(ROBOT_OBS_NAMES)
    return {
        calvin.STATIC_CAMERA_KEY: {"dtype": image_dtype, "shape": tuple(static_shape), "names": hwc},
        calvin.GRIPPER_CAMERA_KEY: {"dtype": image_dtype, "shape": tuple(gripper_shape), "names": hwc},
        STATE_KEY: {"dtype": "float32", "shape": (state_dim,), "names": list(ROBOT_OBS_NAMES)},
        ENV_STATE_KEY: {"dtype": "float32", "shape": (len(SCENE_OBS_NAMES),), "names": list(SCENE_OBS_NAMES)},
        STATE_HISTORY_KEY: {"dtype": "float32", "shape": (options.history_length, state_dim), "names": None},
        SUBGOAL_TRACE_KEY: {"dtype": "float32", "shape": (options.trace_length, state_dim), "names": None},
        ACTION_KEY: {"dtype": "float32", "shape": (len(ACTION_NAMES),), "names": list(ACTION_NAMES)},
        calvin.FRAME_INDEX_KEY: {"dtype": "int64", "shape": (1,), "names": None},
    }


def episode_arrays(
    split: CalvinSplit, episode: EpisodeSpec, options: ConversionOptions
) -> dict[str, np.ndarray]:
    """All per-frame arrays of one episode, already in the contract's dtypes.

    Returns:
        ``{feature_key: (F, ...) array}`` plus ``"task"`` (F,) object array.
    """
    frame_ids = np.arange(episode.start, episode.end + 1)
    raw = split.load_frames(frame_ids.tolist())
    scene_obs = raw["scene_obs"].copy()  # (F, 24)
    scenes = [split.scene_of(int(i)) for i in frame_ids]
    for scene in sorted(set(scenes)):
        mask = np.array([s == scene for s in scenes])
        scene_obs[mask] = canonicalize_scene_obs(raw["scene_obs"][mask], block_order_of(scene))
    robot_obs = raw["robot_obs"].astype(np.float32)  # (F, 15)
    window = options.window
    return {
        calvin.STATIC_CAMERA_KEY: raw["rgb_static"],
        calvin.GRIPPER_CAMERA_KEY: raw["rgb_gripper"],
        STATE_KEY: robot_obs,
        ENV_STATE_KEY: scene_obs.astype(np.float32),
        STATE_HISTORY_KEY: window.histories(robot_obs),  # (F, h, p)
        SUBGOAL_TRACE_KEY: window.traces(robot_obs),  # (F, M, p)
        ACTION_KEY: raw["rel_actions"].astype(np.float32),
        calvin.FRAME_INDEX_KEY: frame_ids.astype(np.int64)[:, None],  # (F, 1)
        TASK_KEY: np.array(episode.tasks, dtype=object),
    }


def iter_frames(arrays: dict[str, np.ndarray]) -> Iterator[dict]:
    """Per-frame dicts for ``LeRobotDataset.add_frame`` (``task`` as a plain str)."""
    for t in range(len(arrays[TASK_KEY])):
        yield {key: (str(value[t]) if key == TASK_KEY else value[t]) for key, value in arrays.items()}


@dataclass(frozen=True)
class PartJob:
    """One part-dataset to write (picklable: sent to worker processes)."""

    index: int
    parts_dir: Path
    repo_id: str
    split_dir: Path
    episodes: tuple[EpisodeSpec, ...]
    features: dict
    options: ConversionOptions

    @property
    def final_dir(self) -> Path:
        """``parts/part-XXXXXX`` (exists only once the part is complete)."""
        return self.parts_dir / f"part-{self.index:06d}"


def _embed_images_if_any(embed: Callable) -> Callable:
    """Wrap LeRobot's ``embed_images`` so a table without image columns is returned as it is.

    Why: LeRobot runs ``datasets.map(embed_table_storage)`` row by row over every saved episode, which for
    video datasets (no image column: the frames are in the videos) changes nothing but costs 1.3 ms of CPU
    per frame with our 2-D columns (measured), about 8 % of a converted frame. Tables with images go through
    ``embed`` unchanged.
    """
    import datasets

    def has_images(feature: object) -> bool:
        if isinstance(feature, datasets.Image):
            return True
        if isinstance(feature, dict):
            return any(has_images(value) for value in feature.values())
        if isinstance(feature, list | tuple):
            return any(has_images(value) for value in feature)
        inner = getattr(feature, "feature", None)
        return inner is not None and has_images(inner)

    def wrapped(dataset):
        return embed(dataset) if has_images(dataset.features) else dataset

    return wrapped


def write_part(job: PartJob) -> int:
    """Write one part-dataset atomically; returns its number of frames."""
    from lerobot.datasets import LeRobotDataset
    from lerobot.datasets import dataset_writer as writer_module

    tmp_dir = job.final_dir.with_suffix(".tmp")
    shutil.rmtree(tmp_dir, ignore_errors=True)
    split = CalvinSplit(job.split_dir)
    use_videos = job.options.image_format == "video"
    encoding = encoder_options(use_videos, max(episode.length for episode in job.episodes))
    dataset = LeRobotDataset.create(
        repo_id=f"{job.repo_id}-{job.final_dir.name}",
        fps=CALVIN_FPS,
        features=job.features,
        root=tmp_dir,
        robot_type=calvin.ROBOT_TYPE,
        video_backend="pyav",  # decoding backend; avoids probing torchcodec, which needs system FFmpeg
        use_videos=use_videos,
        # Frames that are not streamed to the encoder are written as PNG files, off the main thread.
        image_writer_threads=0 if encoding["streaming_encoding"] else 4,
        **encoding,
    )
    frames = 0
    embed = _embed_images_if_any(writer_module.embed_images)
    # Read + decompress episode i+1 (zlib and numpy release the GIL) while LeRobot encodes episode i.
    with mock.patch.object(writer_module, "embed_images", embed), ThreadPoolExecutor(max_workers=1) as reader:
        pending = reader.submit(episode_arrays, split, job.episodes[0], job.options)
        for i, episode in enumerate(job.episodes):
            arrays = pending.result()
            if i + 1 < len(job.episodes):
                pending = reader.submit(episode_arrays, split, job.episodes[i + 1], job.options)
            # LeRobot registers an episode's tasks in set order (string-hash order, which differs between
            # processes); registering them first in order of appearance makes task indices reproducible.
            dataset.meta.save_episode_tasks(list(dict.fromkeys(episode.tasks)))
            for frame in iter_frames(arrays):
                dataset.add_frame(frame)
            dataset.save_episode()
            frames += episode.length
    dataset.finalize()
    check_video_frames(tmp_dir)  # a part with a dropped frame is never renamed into place
    tmp_dir.rename(job.final_dir)
    return frames


def _with_plain_array_columns(update: Callable) -> Callable:
    """Wrap ``aggregate.update_data_df`` so 2-D columns leave it as plain object columns.

    Why: with ``datasets`` imported, pandas reads our Array2D columns (state_history, subgoal_trace) as
    ``datasets``' ``PandasArrayExtensionDtype``, which pyarrow cannot convert back (``ArrowTypeError: Did not
    pass numpy.dtype object``) and pandas cannot concatenate (its ``_metadata`` is a str). Turning every such
    cell into a list of 1-D rows restores the ``list<list<float>>`` layout LeRobot itself writes.
    """

    def wrapped(df, src_meta, dst_meta):
        df = update(df, src_meta, dst_meta)
        for column in df.columns:
            if type(df[column].dtype).__name__ == "PandasArrayExtensionDtype":
                df[column] = pd.Series(
                    [list(cell) for cell in df[column].to_numpy()], dtype=object, index=df.index
                )
        return df

    return wrapped


def merge_parts(part_dirs: list[Path], repo_id: str, merged_dir: Path) -> None:
    """Merge complete part-datasets, in order, with LeRobot's ``aggregate_datasets`` (0.6.1 public API)."""
    from lerobot.datasets import aggregate as aggregate_module

    shutil.rmtree(merged_dir, ignore_errors=True)
    patched = _with_plain_array_columns(aggregate_module.update_data_df)
    with mock.patch.object(aggregate_module, "update_data_df", patched):
        aggregate_module.aggregate_datasets(
            repo_ids=[f"{repo_id}-{path.name}" for path in part_dirs],
            roots=part_dirs,
            aggr_repo_id=repo_id,
            aggr_root=merged_dir,
            # One parquet per part: appending re-reads the merged file through ``datasets`` and hits the same
            # extension dtype inside ``pd.concat``; videos are still concatenated.
            concatenate_data=False,
        )
