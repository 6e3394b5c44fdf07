"""``subgoalvla-add-traces``: history and trace columns for any LeRobotDataset, input untouched, bad input one
line."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers.robot_datasets import make_robot_dataset

from lerobot_subgoalvla.contract.keys import STATE_HISTORY_KEY, STATE_KEY, SUBGOAL_TRACE_KEY
from lerobot_subgoalvla.contract.metadata import ProprioMetadata
from lerobot_subgoalvla.contract.window import TraceWindow
from lerobot_subgoalvla.datasets_conversion.add_traces import add_traces

ENV = {"HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"}


def _digest(root: Path) -> str:
    """A hash of every file under ``root`` (names and bytes): the input must not change."""
    digest = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        digest.update(str(path.relative_to(root)).encode() + path.read_bytes())
    return digest.hexdigest()


@pytest.fixture(scope="module")
def raw(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("add_traces") / "raw"
    make_robot_dataset(root, {"observation.image": 16}, state_dim=3, action_dim=2, use_videos=False, fps=30)
    return root


def _cli(*args: str) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "lerobot_subgoalvla.datasets_conversion.add_traces", *args]
    return subprocess.run(command, capture_output=True, text=True, env=ENV, timeout=300, check=False)


def test_columns_are_the_windows_of_each_episode_and_the_metadata_is_recorded(
    raw: Path, tmp_path: Path
) -> None:
    before = _digest(raw)
    out = add_traces("local/robot", raw, tmp_path / "out", angle_dims=(2,), angle_home=(0.5,))
    assert _digest(raw) == before  # the input is never changed
    window = TraceWindow.for_fps(30)
    metadata = ProprioMetadata.from_features(out.meta.features)
    assert (
        metadata.window == window
        and metadata.angle_dims == (2,)
        and metadata.writer == "subgoalvla-add-traces"
    )
    assert out.meta.features[STATE_HISTORY_KEY]["shape"] == (15, 3)
    assert out.num_frames == 48 and out.num_episodes == 2
    episode = out.meta.episodes[1]
    rows = range(episode["dataset_from_index"], episode["dataset_to_index"])
    states = np.stack([out[i][STATE_KEY].numpy() for i in rows])
    np.testing.assert_array_equal(
        np.stack([out[i][SUBGOAL_TRACE_KEY].numpy() for i in rows]), window.traces(states)
    )
    np.testing.assert_array_equal(
        np.stack([out[i][STATE_HISTORY_KEY].numpy() for i in rows]), window.histories(states)
    )
    assert not (tmp_path / "out.partial").exists()


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--angle-dims", "5", "--angle-home", "0"], "index 5 is out of range"),
        (["--angle-dims", "1,2", "--angle-home", "0"], "--angle-home needs one value per --angle-dims entry"),
        (["--trace-start", "30"], "has 24 frames but the trace window reaches"),
        (["--history-length", "0"], "history_length must be a positive integer"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(
    raw: Path, tmp_path: Path, flags: list[str], message: str
) -> None:
    before = _digest(raw)
    result = _cli(
        "--repo-id", "local/robot", "--root", str(raw), "--output-root", str(tmp_path / "out"), *flags
    )
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert message in lines[-1] and "Traceback" not in result.stderr
    assert not (tmp_path / "out").exists() and _digest(raw) == before


def test_a_dataset_that_already_has_the_columns_or_no_state_is_refused(raw: Path, tmp_path: Path) -> None:
    add_traces("local/robot", raw, tmp_path / "once")
    result = _cli(
        "--repo-id", "local/robot", "--root", str(tmp_path / "once"), "--output-root", str(tmp_path / "twice")
    )
    assert result.returncode == 1 and "already has" in result.stderr.strip().splitlines()[-1]
    result = _cli("--repo-id", "local/robot", "--root", str(raw), "--output-root", str(raw))
    assert result.returncode == 1 and "must differ from --root" in result.stderr
    existing = tmp_path / "existing"
    existing.mkdir()
    (existing / "keep.txt").write_text("mine")
    result = _cli("--repo-id", "local/robot", "--root", str(raw), "--output-root", str(existing))
    assert result.returncode == 1 and "already exists" in result.stderr
    assert (existing / "keep.txt").read_text() == "mine"
