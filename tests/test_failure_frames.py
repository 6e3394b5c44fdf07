"""The failure contact sheet of a study run: it shows failed episodes only, the least successful task first,
finds videos of a moved evaluation folder, and says in one line what is missing."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import av
import numpy as np
import pytest
from helpers.study import study_module


@pytest.fixture
def failure_frames(monkeypatch: pytest.MonkeyPatch):
    yield from study_module(monkeypatch, "failure_frames")


def _write_video(path: Path, num_frames: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w") as container:
        stream = container.add_stream("mpeg4", rate=10)
        stream.width = stream.height = 32
        stream.pix_fmt = "yuv420p"
        for i in range(num_frames):
            image = np.full((32, 32, 3), 10 * i, dtype=np.uint8)
            container.mux(stream.encode(av.VideoFrame.from_ndarray(image, format="rgb24")))
        container.mux(stream.encode())


def _write_eval(eval_dir: Path, task: str, successes: list[bool], recorded_root: str = "gone") -> None:
    """``eval_info.json`` as lerobot-eval writes it, its video paths under a folder that has since moved."""
    videos = []
    for episode in range(len(successes)):
        relative = Path("videos") / f"{task}_0" / f"eval_episode_{episode}.mp4"
        _write_video(eval_dir / task / relative, num_frames=12)
        videos.append(f"{recorded_root}/{task}/{relative}")
    metrics = {"successes": successes, "video_paths": videos}
    info = {
        "per_task": [{"task_group": task, "task_id": 0, "metrics": metrics}],
        "overall": {"video_paths": videos},
    }
    (eval_dir / task / "eval_info.json").write_text(json.dumps(info))


def test_failed_episodes_only_least_successful_task_first(failure_frames, tmp_path: Path) -> None:
    _write_eval(tmp_path, "reach", [True, False, False])
    _write_eval(tmp_path, "push", [False, True, True])
    _write_eval(tmp_path, "drawer", [True, True])
    episodes = failure_frames.failed_episodes(tmp_path, per_task=2)
    assert [(e.task, e.episode) for e in episodes] == [("reach", 1), ("reach", 2), ("push", 0)]
    assert all(e.video.is_file() for e in episodes)


def test_frames_are_evenly_spaced_first_and_last_included(failure_frames, tmp_path: Path) -> None:
    _write_eval(tmp_path, "reach", [False])
    video = failure_frames.failed_episodes(tmp_path, per_task=1)[0].video
    indices, images = failure_frames.video_frames(video, 4)
    assert indices == [0, 4, 7, 11]
    assert [image.shape for image in images] == [(32, 32, 3)] * 4
    assert images[-1].mean() > images[0].mean() + 50  # the last frame is the brightest one written


def test_the_sheet_is_written(failure_frames, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _write_eval(tmp_path / "eval", "reach", [False, True])
    output = tmp_path / "sheet" / "failure_frames.png"
    monkeypatch.setattr(sys, "argv", ["failure_frames", str(tmp_path / "eval"), "--output", str(output)])
    failure_frames.main()
    assert output.read_bytes()[:4] == b"\x89PNG"
    assert not output.with_suffix(".partial.png").exists()


def test_a_task_not_evaluated_is_named(failure_frames, tmp_path: Path) -> None:
    _write_eval(tmp_path, "reach", [False])
    with pytest.raises(SystemExit, match="no evaluation at .*push"):
        failure_frames.failed_episodes(tmp_path, per_task=1, tasks=["push"])
    (tmp_path / "reach" / "videos" / "reach_0" / "eval_episode_0.mp4").unlink()
    with pytest.raises(SystemExit, match="eval_episode_0.mp4 is not there"):
        failure_frames.failed_episodes(tmp_path, per_task=1)
