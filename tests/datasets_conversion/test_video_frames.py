"""Videos keep every recorded frame: encoder options that cannot drop one, and the check that finds one."""

from __future__ import annotations

import shutil
from pathlib import Path

import av
import pytest
from helpers.lerobot_datasets import make_tiny_calvin_dataset

from lerobot_subgoalvla.datasets_conversion.video_frames import (
    MAX_STREAMED_FRAMES,
    check_video_frames,
    count_video_frames,
    encoder_options,
)


def test_encoder_queue_holds_a_whole_episode_so_put_never_waits() -> None:
    assert encoder_options(True, 360) == {"streaming_encoding": True, "encoder_queue_maxsize": 361}
    assert encoder_options(True, MAX_STREAMED_FRAMES + 1) == {"streaming_encoding": False}
    assert encoder_options(False, 10) == {"streaming_encoding": False}


def _drop_last_frame(path: Path) -> None:
    """Remux ``path`` without its last packet (a frame dropped by a full encoder queue)."""
    copy = path.with_name("copy.mp4")
    with av.open(str(path)) as source, av.open(str(copy), "w") as target:
        stream = source.streams.video[0]
        out = target.add_stream_from_template(stream, opaque=True)
        packets = [packet for packet in source.demux(stream) if packet.size]
        for packet in packets[:-1]:
            packet.stream = out
            target.mux(packet)
    shutil.move(copy, path)


@pytest.fixture(scope="module")
def video_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("video") / "ds"
    make_tiny_calvin_dataset(
        root, num_episodes=3, episode_len=7, static_size=64, gripper_size=64, use_videos=True
    )
    return root


def test_complete_videos_pass_and_are_counted_per_file(video_dataset: Path) -> None:
    assert check_video_frames(video_dataset) == 2  # one file per camera
    for path in video_dataset.glob("videos/*/chunk-*/*.mp4"):
        assert count_video_frames(path) == 21


def test_a_missing_frame_is_one_line_naming_the_file(video_dataset: Path, tmp_path: Path) -> None:
    damaged = tmp_path / "ds"
    shutil.copytree(video_dataset, damaged)
    video = next(damaged.glob("videos/observation.images.gripper/chunk-*/*.mp4"))
    _drop_last_frame(video)
    with pytest.raises(ValueError, match=r"file-000\.mp4: 20 frames encoded for 21 recorded ones") as error:
        check_video_frames(damaged)
    assert "\n" not in str(error.value) and "write it again" in str(error.value)


def _write_with_stalled_encoder(root: Path, frames: int, monkeypatch: pytest.MonkeyPatch, **encoding) -> None:
    """One episode written while the encoder thread stalls for 0.5 s at its start (a busy machine)."""
    import time

    import numpy as np
    from lerobot.datasets import LeRobotDataset, video_utils

    run = video_utils._CameraEncoderThread.run  # private: the only way to stall LeRobot's encoder in a test

    def stalled(self) -> None:
        time.sleep(0.5)
        run(self)

    monkeypatch.setattr(video_utils._CameraEncoderThread, "run", stalled)
    features = {"observation.images.cam": {"dtype": "video", "shape": (64, 64, 3), "names": ["h", "w", "c"]}}
    dataset = LeRobotDataset.create("local/stall", fps=30, features=features, root=root, **encoding)
    for t in range(frames):
        dataset.add_frame({"observation.images.cam": np.full((64, 64, 3), t, np.uint8), "task": "stall"})
    dataset.save_episode()
    dataset.finalize()


def test_a_stalled_encoder_drops_frames_at_lerobots_default_but_not_with_our_queue(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _write_with_stalled_encoder(tmp_path / "default", 60, monkeypatch, streaming_encoding=True)
    with pytest.raises(ValueError, match="frames encoded for 60 recorded ones"):
        check_video_frames(tmp_path / "default")
    _write_with_stalled_encoder(tmp_path / "ours", 60, monkeypatch, **encoder_options(True, 60))
    assert check_video_frames(tmp_path / "ours") == 1
