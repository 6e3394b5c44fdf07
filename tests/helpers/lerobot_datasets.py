"""A factory for tiny CALVIN-style LeRobotDatasets that follow the data contract (docs/architecture.md).

The frames are synthetic but consistent: the robot state integrates the actions (so actions are predictable
from state changes), the cameras show the episode's colour with a bright square at a state-dependent position,
and the history / trace columns are computed with the contract's ``TraceWindow`` and carry its metadata
(CALVIN's angle dims), exactly as the converter writes them. Built with LeRobot's write protocol
(``create`` -> ``add_frame`` -> ``save_episode`` -> ``finalize``).

Usage::

    from helpers.lerobot_datasets import make_tiny_calvin_dataset
    ds = make_tiny_calvin_dataset(tmp_path / "ds", num_episodes=2, episode_len=12, static_size=32,
    gripper_size=16) # lerobot-train --dataset.repo_id=local/tiny_calvin --dataset.root=<tmp_path/ds>
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from lerobot.datasets import LeRobotDataset

from lerobot_subgoalvla.calvin_vocab import ACTION_NAMES, CALVIN_FPS, EVAL_INSTRUCTIONS, ROBOT_OBS_NAMES
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

DEFAULT_REPO_ID = "local/tiny_calvin"
#: Instructions cycled over the episodes (CALVIN's evaluation phrasing).
INSTRUCTIONS: tuple[str, ...] = (
    EVAL_INSTRUCTIONS["open_drawer"],
    EVAL_INSTRUCTIONS["push_red_block_left"],
    EVAL_INSTRUCTIONS["turn_on_lightbulb"],
)
STATE_DIM, ACTION_DIM, SCENE_DIM = len(ROBOT_OBS_NAMES), len(ACTION_NAMES), 24


def tiny_calvin_features(
    static_size: int, gripper_size: int, use_videos: bool, window: TraceWindow
) -> dict[str, dict]:
    """LeRobot feature schema of the data contract at the given image sizes, with the trace metadata."""
    image_dtype = "video" if use_videos else "image"
    hwc = ["height", "width", "channels"]
    features = {
        calvin.STATIC_CAMERA_KEY: {
            "dtype": image_dtype,
            "shape": (static_size, static_size, 3),
            "names": hwc,
        },
        calvin.GRIPPER_CAMERA_KEY: {
            "dtype": image_dtype,
            "shape": (gripper_size, gripper_size, 3),
            "names": hwc,
        },
        STATE_KEY: {"dtype": "float32", "shape": (STATE_DIM,), "names": list(ROBOT_OBS_NAMES)},
        ENV_STATE_KEY: {"dtype": "float32", "shape": (SCENE_DIM,), "names": None},
        STATE_HISTORY_KEY: {"dtype": "float32", "shape": (window.history_length, STATE_DIM), "names": None},
        SUBGOAL_TRACE_KEY: {"dtype": "float32", "shape": (window.trace_length, STATE_DIM), "names": None},
        ACTION_KEY: {"dtype": "float32", "shape": (ACTION_DIM,), "names": list(ACTION_NAMES)},
        calvin.FRAME_INDEX_KEY: {"dtype": "int64", "shape": (1,), "names": None},
    }
    metadata = ProprioMetadata(
        window, CALVIN_FPS, calvin.ANGLE_DIMS, calvin.ANGLE_HOME, tuple(EVAL_INSTRUCTIONS.values()), "tests"
    )
    return metadata.attach(features)


def _episode_arrays(rng: np.random.Generator, episode_len: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smooth actions, the states they drive (robot_obs) and a static scene_obs for one episode."""
    phase = rng.uniform(0, 2 * np.pi, size=ACTION_DIM)
    t = np.arange(episode_len)[:, None]
    actions = np.clip(np.sin(0.3 * t + phase), -1, 1).astype(np.float32)  # (T, 7)
    actions[:, -1] = np.where(actions[:, -1] >= 0, 1.0, -1.0)  # binary gripper, as in CALVIN
    states = np.zeros((episode_len, STATE_DIM), dtype=np.float32)
    states[0] = rng.normal(0, 0.1, size=STATE_DIM)
    for i in range(1, episode_len):
        states[i] = states[i - 1]
        states[i, :6] += 0.02 * actions[i - 1, :6]  # tcp pos / euler follow the relative actions
        states[i, 6] = 0.04 * (actions[i - 1, 6] + 1)  # gripper opening width
        states[i, 14] = actions[i - 1, 6]  # gripper action
    scene = np.tile(rng.normal(0, 0.1, size=SCENE_DIM).astype(np.float32), (episode_len, 1))
    return actions, states, scene


def _render(size: int, colour: np.ndarray, state: np.ndarray) -> np.ndarray:
    """An HxWx3 uint8 frame: the episode colour with a white square placed by the tcp x/y."""
    image = np.broadcast_to(colour, (size, size, 3)).copy()
    half = max(1, size // 8)
    cx = int(np.clip((0.5 + 2 * state[0]) * size, half, size - half))
    cy = int(np.clip((0.5 + 2 * state[1]) * size, half, size - half))
    image[cy - half : cy + half, cx - half : cx + half] = 255
    return image


def make_tiny_calvin_dataset(
    root: str | Path,
    num_episodes: int = 2,
    episode_len: int = 12,
    static_size: int = 32,
    gripper_size: int = 16,
    use_videos: bool = False,
    repo_id: str = DEFAULT_REPO_ID,
    seed: int = 0,
    history_length: int = PAPER_HISTORY_LENGTH,
    trace_start: int = PAPER_TRACE_START,
    trace_length: int = PAPER_TRACE_LENGTH,
    drop_features: tuple[str, ...] = (),
) -> LeRobotDataset:
    """Write a tiny CALVIN-style dataset at ``root`` (must not exist) and return it opened for reading.

    Args:
        root: dataset directory (LeRobot refuses an existing one).
        num_episodes: episodes to write; instructions cycle through ``INSTRUCTIONS``.
        episode_len: frames per episode.
        static_size: side of the square static camera (200 in CALVIN; keep it small in tests).
        gripper_size: side of the square gripper camera (84 in CALVIN).
        use_videos: store cameras as AV1 videos (slow to encode) instead of PNG images in the parquet files.
        repo_id: the dataset's label (``--dataset.repo_id``).
        seed: seed of the synthetic trajectories.
        history_length, trace_start, trace_length: the window, recorded in the trace feature's metadata.
        drop_features: contract keys to leave out (to test the policy's missing-feature errors).

    Returns:
        The finalized dataset, re-opened from ``root``.
    """
    root = Path(root)
    rng = np.random.default_rng(seed)
    window = TraceWindow(history_length, trace_start, trace_length)
    features = tiny_calvin_features(static_size, gripper_size, use_videos, window)
    features = {key: value for key, value in features.items() if key not in drop_features}
    dataset = LeRobotDataset.create(
        repo_id=repo_id,
        fps=CALVIN_FPS,
        features=features,
        root=root,
        robot_type="franka",
        use_videos=use_videos,
    )
    frame_index = 0
    for episode in range(num_episodes):
        actions, states, scene = _episode_arrays(rng, episode_len)
        histories, traces = window.histories(states), window.traces(states)  # (T, h, 15), (T, M, 15)
        colour = rng.integers(0, 200, size=3, dtype=np.uint8)
        for t in range(episode_len):
            frame = {
                calvin.STATIC_CAMERA_KEY: _render(static_size, colour, states[t]),
                calvin.GRIPPER_CAMERA_KEY: _render(gripper_size, colour[::-1], states[t]),
                STATE_KEY: states[t],
                ENV_STATE_KEY: scene[t],
                STATE_HISTORY_KEY: histories[t],
                SUBGOAL_TRACE_KEY: traces[t],
                ACTION_KEY: actions[t],
                calvin.FRAME_INDEX_KEY: np.array([frame_index], dtype=np.int64),
                TASK_KEY: INSTRUCTIONS[episode % len(INSTRUCTIONS)],
            }
            dataset.add_frame({key: value for key, value in frame.items() if key not in drop_features})
            frame_index += 1
        dataset.save_episode()
    dataset.finalize()
    return LeRobotDataset(repo_id, root=root)
