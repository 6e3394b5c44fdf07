"""Tiny synthetic LeRobotDatasets of *any* robot: N cameras, a p-dim state, an A-dim action, no trace columns.

What a LeRobot user brings (PushT-like, ALOHA-like, Meta-World-like layouts), written with LeRobot's own
protocol (``create`` -> ``add_frame`` -> ``save_episode`` -> ``finalize``). The state integrates the actions
and the cameras show a square placed by the state, so the data is consistent, not noise.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from lerobot.datasets import LeRobotDataset

from lerobot_subgoalvla.contract.keys import ACTION_KEY, STATE_KEY, TASK_KEY

HWC = ["height", "width", "channels"]
TASKS = ("push the block to the goal", "fold the towel")


def make_robot_dataset(
    root: Path,
    cameras: dict[str, int],
    state_dim: int,
    action_dim: int,
    use_videos: bool,
    num_episodes: int = 2,
    episode_len: int = 24,
    fps: int = 10,
    repo_id: str = "local/robot",
    seed: int = 0,
) -> LeRobotDataset:
    """Write the dataset at ``root``; ``cameras`` maps feature keys to square image sides."""
    rng = np.random.default_rng(seed)
    dtype = "video" if use_videos else "image"
    features = {
        key: {"dtype": dtype, "shape": (side, side, 3), "names": HWC} for key, side in cameras.items()
    }
    features[STATE_KEY] = {"dtype": "float32", "shape": (state_dim,), "names": None}
    features[ACTION_KEY] = {"dtype": "float32", "shape": (action_dim,), "names": None}
    dataset = LeRobotDataset.create(repo_id, fps, features=features, root=root, use_videos=use_videos)
    for episode in range(num_episodes):
        actions = rng.uniform(-1, 1, size=(episode_len, action_dim)).astype(np.float32)
        states = np.cumsum(0.05 * np.resize(actions, (episode_len, state_dim)), axis=0).astype(np.float32)
        for t in range(episode_len):
            frame = {key: _image(side, states[t], k) for k, (key, side) in enumerate(cameras.items())}
            frame.update(
                {STATE_KEY: states[t], ACTION_KEY: actions[t], TASK_KEY: TASKS[episode % len(TASKS)]}
            )
            dataset.add_frame(frame)
        dataset.save_episode()
    dataset.finalize()
    return LeRobotDataset(repo_id, root=root)


def _image(side: int, state: np.ndarray, camera: int) -> np.ndarray:
    image = np.full((side, side, 3), 40 * camera, dtype=np.uint8)
    x = int(np.clip((0.5 + state[0]) * side, 1, side - 2))
    image[max(0, x - 2) : x + 2, :, camera % 3] = 255
    return image


def make_robot_dataset_in_subprocess(
    root: Path, cameras: dict[str, int], state_dim: int, action_dim: int, use_videos: bool
) -> None:
    """``make_robot_dataset`` in a fresh interpreter.

    Why: LeRobot encodes each camera's video in a forked process pool; forked from a pytest process that has
    loaded the whole test session (torch, scipy, pybullet, ...) SVT-AV1 dies with a floating-point exception,
    while the same call in a fresh interpreter (as a user's script runs it) works.
    """
    import json
    import os
    import subprocess
    import sys

    code = (
        "import json, sys; from pathlib import Path; from helpers.robot_datasets import make_robot_dataset; "
        "a = json.loads(sys.argv[1]); make_robot_dataset(Path(a['root']), a['cameras'], a['state_dim'], "
        "a['action_dim'], a['use_videos'])"
    )
    args = {
        "root": str(root),
        "cameras": cameras,
        "state_dim": state_dim,
        "action_dim": action_dim,
        "use_videos": use_videos,
    }
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]), "OMP_NUM_THREADS": "1"}
    result = subprocess.run(
        [sys.executable, "-c", code, json.dumps(args)], capture_output=True, text=True, env=env, timeout=300
    )
    if result.returncode != 0:
        raise RuntimeError(result.stderr[-2000:])
