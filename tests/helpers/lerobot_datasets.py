"""A factory for tiny CALVIN-style LeRobotDatasets that follow the data contract (DESIGN.md "Data contract").

The frames are synthetic but consistent: the robot state integrates the actions (so actions are predictable
from state changes), the cameras show the episode's colour with a bright square at a state-dependent position,
and the history / trace columns are computed with the project's own ``subgoal_traces`` functions, exactly as
the converter does. Built with LeRobot's write protocol (``create`` -> ``add_frame`` -> ``save_episode`` ->
``finalize``).

Usage::

    from helpers.lerobot_datasets import make_tiny_calvin_dataset
    ds = make_tiny_calvin_dataset(tmp_path / "ds", num_episodes=2, episode_len=12, static_size=32,
    gripper_size=16) # lerobot-train --dataset.repo_id=local/tiny_calvin --dataset.root=<tmp_path/ds>
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from lerobot.datasets import LeRobotDataset

from lerobot_subgoalvla.calvin_vocab import ACTION_NAMES, CALVIN_FPS, EVAL_INSTRUCTIONS, ROBOT_OBS_NAMES
from lerobot_subgoalvla.datasets_conversion.subgoal_traces import (
    DEFAULT_HISTORY_LENGTH,
    DEFAULT_TRACE_LENGTH,
    DEFAULT_TRACE_START,
    state_history,
    subgoal_traces,
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
    static_size: int, gripper_size: int, use_videos: bool, history_length: int, trace_length: int
) -> dict[str, dict]:
    """LeRobot feature schema of the data contract at the given image sizes."""
    image_dtype = "video" if use_videos else "image"
    hwc = ["height", "width", "channels"]
    return {
        "observation.images.static": {
            "dtype": image_dtype,
            "shape": (static_size, static_size, 3),
            "names": hwc,
        },
        "observation.images.gripper": {
            "dtype": image_dtype,
            "shape": (gripper_size, gripper_size, 3),
            "names": hwc,
        },
        "observation.state": {"dtype": "float32", "shape": (STATE_DIM,), "names": list(ROBOT_OBS_NAMES)},
        "observation.environment_state": {"dtype": "float32", "shape": (SCENE_DIM,), "names": None},
        "observation.state_history": {
            "dtype": "float32",
            "shape": (history_length, STATE_DIM),
            "names": None,
        },
        "observation.subgoal_trace": {"dtype": "float32", "shape": (trace_length, STATE_DIM), "names": None},
        "action": {"dtype": "float32", "shape": (ACTION_DIM,), "names": list(ACTION_NAMES)},
        "calvin_frame_index": {"dtype": "int64", "shape": (1,), "names": None},
    }


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
    history_length: int = DEFAULT_HISTORY_LENGTH,
    trace_start: int = DEFAULT_TRACE_START,
    trace_length: int = DEFAULT_TRACE_LENGTH,
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
        history_length, trace_start, trace_length: the converter options, recorded in ``meta/info.json``.
        drop_features: contract keys to leave out (to test the policy's missing-feature errors).

    Returns:
        The finalized dataset, re-opened from ``root``.
    """
    root = Path(root)
    rng = np.random.default_rng(seed)
    features = tiny_calvin_features(static_size, gripper_size, use_videos, history_length, trace_length)
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
        histories = state_history(states, history_length)  # (T, L_h, 15)
        traces = subgoal_traces(states, trace_start, trace_length)  # (T, L_s, 15)
        colour = rng.integers(0, 200, size=3, dtype=np.uint8)
        for t in range(episode_len):
            frame = {
                "observation.images.static": _render(static_size, colour, states[t]),
                "observation.images.gripper": _render(gripper_size, colour[::-1], states[t]),
                "observation.state": states[t],
                "observation.environment_state": scene[t],
                "observation.state_history": histories[t],
                "observation.subgoal_trace": traces[t],
                "action": actions[t],
                "calvin_frame_index": np.array([frame_index], dtype=np.int64),
                "task": INSTRUCTIONS[episode % len(INSTRUCTIONS)],
            }
            dataset.add_frame({key: value for key, value in frame.items() if key not in drop_features})
            frame_index += 1
        dataset.save_episode()
    dataset.finalize()
    info_path = root / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    info["subgoalvla"] = {
        "trace_start": trace_start,
        "trace_length": trace_length,
        "history_length": history_length,
    }
    info_path.write_text(json.dumps(info, indent=4))
    return LeRobotDataset(repo_id, root=root)
