"""subgoalvla-dataset-traces: a dataset episode's ground-truth subgoal traces drawn as ghost robots."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from helpers.lerobot_datasets import make_tiny_calvin_dataset

from lerobot_subgoalvla.visualization import dataset_traces


@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("traces") / "tiny"
    make_tiny_calvin_dataset(root, num_episodes=2, episode_len=12, static_size=32, gripper_size=16)
    return root


def test_one_overlay_per_drawn_frame_of_the_episode(dataset_root: Path) -> None:
    frames = dataset_traces.dataset_trace_frames(dataset_root, episode=1, every=5)
    assert len(frames) == 3  # frames 0, 5 and 10 of 12
    assert all(f.shape == (32, 32, 3) and f.dtype == np.uint8 for f in frames)


def test_cli_writes_the_strip_and_refuses_bad_input(dataset_root: Path, tmp_path: Path, caplog) -> None:
    output = tmp_path / "strip.png"
    assert (
        dataset_traces.main(["--dataset-root", str(dataset_root), "--every", "6", "--output", str(output)])
        == 0
    )
    assert output.is_file() and output.stat().st_size > 0
    for argv, message in [
        (["--dataset-root", str(tmp_path / "nope"), "--output", str(output)], "no meta/info.json"),
        (["--dataset-root", str(dataset_root), "--episode", "7", "--output", str(output)], "episodes 0..1"),
        (["--dataset-root", str(dataset_root), "--output", str(tmp_path / "x.gif")], "use a .mp4"),
    ]:
        caplog.clear()
        with caplog.at_level(logging.ERROR), pytest.raises(SystemExit) as info:
            dataset_traces.main(argv)
        assert info.value.code == 1 and message in caplog.text
