"""LeRobot's own viewer (``lerobot-dataset-viz``, from the ``viz`` extra) on a dataset of ours.

The project's set-up installs the ``viz`` extra, so the viewer works out of the box: it writes a Rerun
recording of the cameras, the state and the action of one episode. (It has no view of our history and
subgoal-trace features; ``subgoalvla-dataset-traces`` draws those.)
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest
from helpers.lerobot_datasets import DEFAULT_REPO_ID, make_tiny_calvin_dataset


def test_lerobot_dataset_viz_records_cameras_state_and_action(tmp_path: Path) -> None:
    viewer = shutil.which("lerobot-dataset-viz")
    assert viewer is not None, "lerobot-dataset-viz missing: install the viz extra (pip install -e '.[viz]')"
    pytest.importorskip("rerun", reason="the viz extra (rerun-sdk) is not installed")
    from rerun.experimental import RrdReader

    root = tmp_path / "tiny"
    make_tiny_calvin_dataset(root, num_episodes=2, episode_len=8, static_size=32, gripper_size=16)
    output = tmp_path / "rrd"
    command = [viewer, "--repo-id", DEFAULT_REPO_ID, "--root", str(root), "--episode-index", "1",
               "--save", "1", "--output-dir", str(output), "--num-workers", "0"]  # fmt: skip
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
    result = subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    (recording,) = output.glob("*.rrd")
    entities = {column.entity_path for column in RrdReader(recording).store().schema().component_columns()}
    assert {"/observation.images.static", "/observation.images.gripper", "/action", "/state"} <= entities
