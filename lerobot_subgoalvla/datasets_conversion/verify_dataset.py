"""``--verify``: reload a converted dataset with LeRobot and compare it with the native source.

Checks (raising ValueError with one line naming the key, episode and fix on the first mismatch):

* the episode list (count, per-episode source frame range via ``calvin_frame_index``, length);
* ``observation.state``, ``action`` and ``observation.environment_state`` equal the source arrays
  (``robot_obs``, ``rel_actions``, block-slot-canonicalised ``scene_obs``) cast to float32 - exactly;
* ``observation.state_history`` / ``observation.subgoal_trace`` equal the contract's window definition
  applied to the episode's states - exactly;
* camera frames, decoded by ``LeRobotDataset.__getitem__`` (``video_backend="pyav"``), against the source
  pixels: exact for ``--image-format image``; for AV1 video the mean absolute error must stay below
  :data:`VIDEO_MEAN_ABS_TOLERANCE`. Decoding every frame would cost as much as the conversion, so images are
  checked on ``image_samples`` evenly spaced frames (all numeric columns are checked on every frame).

Dimension legend:
    N   frames of the dataset, F frames of one episode
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_subgoalvla.contract.calvin import FRAME_INDEX_KEY, GRIPPER_CAMERA_KEY, STATIC_CAMERA_KEY
from lerobot_subgoalvla.contract.keys import (
    ACTION_KEY,
    ENV_STATE_KEY,
    STATE_HISTORY_KEY,
    STATE_KEY,
    SUBGOAL_TRACE_KEY,
)
from lerobot_subgoalvla.datasets_conversion.calvin_format import CalvinSplit
from lerobot_subgoalvla.datasets_conversion.calvin_quirks import EpisodeSpec
from lerobot_subgoalvla.datasets_conversion.lerobot_parts import ConversionOptions, episode_arrays

#: Mean absolute pixel error (in [0, 1]) accepted for AV1 (crf 30) frames;
#: measured ~0.01 on CALVIN-like renders.
VIDEO_MEAN_ABS_TOLERANCE = 0.04
NUMERIC_KEYS = (STATE_KEY, ENV_STATE_KEY, STATE_HISTORY_KEY, SUBGOAL_TRACE_KEY, ACTION_KEY, FRAME_INDEX_KEY)


@dataclass(frozen=True)
class VerifyReport:
    """Outcome of :func:`verify_dataset`."""

    episodes: int
    frames: int
    image_frames_checked: int
    image_max_abs_error: float
    image_mean_abs_error: float

    def summary(self) -> str:
        """One log line."""
        return (
            f"{self.episodes} episodes / {self.frames} frames: numeric columns exact; images on "
            f"{self.image_frames_checked} frames max abs error {self.image_max_abs_error:.4f}, "
            f"mean {self.image_mean_abs_error:.5f} (pixel range [0, 1])"
        )


def _columns(dataset) -> dict[str, np.ndarray]:
    table = dataset.hf_dataset.with_format("numpy")
    return {key: np.asarray(table[key]) for key in (*NUMERIC_KEYS, "episode_index", "task_index")}


def verify_dataset(
    dataset,
    split: CalvinSplit,
    episodes: list[EpisodeSpec],
    options: ConversionOptions,
    image_samples: int = 64,
) -> VerifyReport:
    """Compare ``dataset`` (a LeRobotDataset) with ``episodes`` of ``split``; see the module docstring."""
    columns = _columns(dataset)
    if dataset.num_episodes != len(episodes):
        raise ValueError(
            f"verify: {dataset.num_episodes} episodes written, {len(episodes)} expected; reconvert"
        )
    tasks = dataset.meta.tasks
    task_names = {int(i): str(name) for name, i in zip(tasks.index, tasks["task_index"], strict=True)}
    offset = 0
    for index, episode in enumerate(episodes):
        rows = slice(offset, offset + episode.length)
        if not (columns["episode_index"][rows] == index).all():
            raise ValueError(f"verify: episode {index} has the wrong length or frame order; reconvert")
        expected = episode_arrays(split, episode, options)
        for key in NUMERIC_KEYS:
            written = columns[key][rows].reshape(expected[key].shape)
            if not np.array_equal(written, expected[key]):
                raise ValueError(f"verify: {key} of episode {index} differs from the source; reconvert")
        written_tasks = [task_names[int(i)] for i in columns["task_index"][rows].reshape(-1)]
        if written_tasks != list(episode.tasks):
            raise ValueError(
                f"verify: task strings of episode {index} differ from the annotations; reconvert"
            )
        offset += episode.length
    return _verify_images(dataset, split, columns, options, image_samples, len(episodes))


def _verify_images(dataset, split, columns, options, image_samples: int, num_episodes: int) -> VerifyReport:
    num_frames = len(columns[FRAME_INDEX_KEY])
    indices = np.unique(np.linspace(0, num_frames - 1, num=min(image_samples, num_frames)).astype(int))
    errors_max, errors_mean = [], []
    for index in indices.tolist():
        item = dataset[index]
        source = split.load_frames(
            [int(columns[FRAME_INDEX_KEY][index].reshape(-1)[0])], ("rgb_static", "rgb_gripper")
        )
        for key, raw in (
            (STATIC_CAMERA_KEY, source["rgb_static"][0]),
            (GRIPPER_CAMERA_KEY, source["rgb_gripper"][0]),
        ):
            decoded = item[key].numpy().transpose(1, 2, 0)  # (C, H, W) -> (H, W, C)
            error = np.abs(decoded.astype(np.float64) - raw.astype(np.float64) / 255.0)
            errors_max.append(float(error.max()))
            errors_mean.append(float(error.mean()))
    max_error, mean_error = max(errors_max), float(np.mean(errors_mean))
    if options.image_format == "image" and max_error > 0.5 / 255:
        raise ValueError(
            f"verify: PNG frames differ from the source (max abs error {max_error:.4f}); reconvert"
        )
    if options.image_format == "video" and mean_error > VIDEO_MEAN_ABS_TOLERANCE:
        raise ValueError(
            "verify: video frames differ from the source beyond codec tolerance (mean abs error "
            f"{mean_error:.4f} > "
            f"{VIDEO_MEAN_ABS_TOLERANCE}); check the encoder settings or use --image-format image"
        )
    return VerifyReport(num_episodes, num_frames, len(indices), max_error, mean_error)
