"""Converter: LANG/ALL episodes, the data contract, options in meta, --verify, CLI errors, kill-and-resume."""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from native_fixtures import write_native_split

from lerobot_subgoalvla.contract.metadata import ProprioMetadata
from lerobot_subgoalvla.contract.window import TraceWindow
from lerobot_subgoalvla.datasets_conversion.calvin_format import CalvinSplit, frame_filename
from lerobot_subgoalvla.datasets_conversion.calvin_quirks import PLAY_TASK, canonicalize_scene_obs
from lerobot_subgoalvla.datasets_conversion.convert_calvin import convert, main
from lerobot_subgoalvla.datasets_conversion.lerobot_parts import ConversionOptions
from lerobot_subgoalvla.datasets_conversion.verify_dataset import verify_dataset

SEGMENTS = [(0, 29), (40, 74)]
WINDOWS = [
    (0, 20, "open the drawer", "open_drawer"),
    (10, 35, "press the button", "turn_on_led"),  # crosses the segment end 29 -> clamped
    (45, 70, "lift the red block", "lift_red_block_table"),
]
SCENES = {"calvin_scene_A": (0, 74)}


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("calvin_src")
    write_native_split(root / "training", SEGMENTS, WINDOWS, SCENES, static=64, gripper=64, seed=1)
    write_native_split(root / "validation", [(0, 19)], WINDOWS[:1], static=64, gripper=64, seed=2)
    return root


def _columns(dataset, key: str) -> np.ndarray:
    return np.asarray(dataset.hf_dataset.with_format("numpy")[key])


def test_lang_mode_contract(source: Path, tmp_path: Path) -> None:
    options = ConversionOptions(image_format="image", trace_start=3, trace_length=4, history_length=5)
    dataset = convert(source, "local/lang", tmp_path / "lang", options=options, episodes_per_part=2)[
        "training"
    ]
    assert dataset.num_episodes == 3
    lengths = np.bincount(_columns(dataset, "episode_index"))
    np.testing.assert_array_equal(lengths, [21, 20, 26])  # window 2 clamped to [10, 29]
    frame_ids = _columns(dataset, "calvin_frame_index").reshape(-1)
    np.testing.assert_array_equal(frame_ids[:21], np.arange(0, 21))
    np.testing.assert_array_equal(frame_ids[21:41], np.arange(10, 30))
    state = _columns(dataset, "observation.state")
    np.testing.assert_array_equal(state[:, 0], frame_ids.astype(np.float32))  # source robot_obs[0] == id
    split = CalvinSplit(source / "training")
    raw = split.load_frames(frame_ids[41:].tolist())
    np.testing.assert_array_equal(state[41:], raw["robot_obs"].astype(np.float32))
    np.testing.assert_array_equal(_columns(dataset, "action")[41:], raw["rel_actions"].astype(np.float32))
    expected_env = canonicalize_scene_obs(raw["scene_obs"], ("pink", "blue", "red")).astype(np.float32)
    np.testing.assert_array_equal(_columns(dataset, "observation.environment_state")[41:], expected_env)
    history, trace = (
        _columns(dataset, "observation.state_history"),
        _columns(dataset, "observation.subgoal_trace"),
    )
    assert history.shape == (67, 5, 15) and trace.shape == (67, 4, 15)
    window = TraceWindow(history_length=5, trace_start=3, trace_length=4)
    np.testing.assert_array_equal(history[21:41], window.histories(state[21:41]))
    np.testing.assert_array_equal(trace[21:41], window.traces(state[21:41]))
    np.testing.assert_array_equal(trace[40, :, 0], [29, 29, 29, 29])  # clamped to the episode's last frame
    assert [dataset[i]["task"] for i in (0, 21, 41)] == [
        "open the drawer",
        "press the button",
        "lift the red block",
    ]
    info = json.loads((tmp_path / "lang" / "meta" / "info.json").read_text())
    assert "subgoalvla" not in info  # LeRobot would warn about an unknown top-level field at every load
    metadata = ProprioMetadata.from_features(info["features"])
    assert metadata.window == window and metadata.fps == 30 and metadata.angle_dims == (3, 4, 5)
    assert metadata.extra["block_order"] == ["red", "blue", "pink"] and metadata.extra["mode"] == "lang"
    assert "pull the handle to open the drawer" in metadata.instructions  # CALVIN's evaluation phrasing
    assert str(tmp_path) not in json.dumps(info)  # no local path is published with the dataset
    assert str(tmp_path) not in (tmp_path / "lang" / "README.md").read_text()
    assert info["features"]["observation.images.static"]["dtype"] == "image"
    assert (tmp_path / "lang" / "README.md").is_file()
    assert not (tmp_path / "lang.partial").exists()


def test_all_mode_and_both_splits(source: Path, tmp_path: Path) -> None:
    options = ConversionOptions(image_format="image", mode="all")
    out = convert(source, "local/all", tmp_path / "all", split="both", options=options)
    training, validation = out["training"], out["validation"]
    assert training.root == tmp_path / "all" / "training" and training.repo_id == "local/all-training"
    np.testing.assert_array_equal(np.bincount(_columns(training, "episode_index")), [30, 35])
    assert validation.num_episodes == 1 and validation.num_frames == 20
    tasks = [training[i]["task"] for i in (0, 9, 10, 21, 29, 30, 45)]
    assert tasks == [
        "open the drawer",
        "open the drawer",
        "press the button",
        "press the button",
        "press the button",
        PLAY_TASK,
        "lift the red block",
    ]


def test_verify_video_dataset(source: Path, tmp_path: Path) -> None:
    dataset = convert(source, "local/video", tmp_path / "video", verify=True, max_episodes=2)["training"]
    assert dataset.meta.features["observation.images.static"]["dtype"] == "video"
    assert sorted(p.name for p in (tmp_path / "video" / "videos").iterdir()) == [
        "observation.images.gripper",
        "observation.images.static",
    ]
    split = CalvinSplit(source / "training")
    from lerobot_subgoalvla.datasets_conversion.convert_calvin import select_episodes

    report = verify_dataset(
        dataset, split, select_episodes(split, "lang", 2), ConversionOptions(), image_samples=8
    )
    assert report.frames == 41 and report.image_frames_checked == 8
    assert 0 < report.image_mean_abs_error < 0.04  # lossy AV1, within tolerance
    item = dataset[5]
    assert item["observation.images.static"].shape == (3, 64, 64)


def _run_main(argv: list[str], caplog: pytest.LogCaptureFixture) -> str:
    caplog.clear()
    with caplog.at_level(logging.ERROR), pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 1
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1 and "\n" not in errors[0]
    return errors[0]


def test_cli_errors(source: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch) -> None:
    base = ["--repo-id", "local/x", "--image-format", "image"]
    message = _run_main([str(tmp_path / "missing"), *base, "--root", str(tmp_path / "o1")], caplog)
    assert f"SRC {tmp_path / 'missing'}: not found; point SRC at a CALVIN dataset folder" in message
    (tmp_path / "exists").mkdir()
    message = _run_main([str(source), *base, "--root", str(tmp_path / "exists")], caplog)
    assert "output folder already exists; pass --overwrite" in message
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    message = _run_main([str(source), *base, "--root", str(tmp_path / "o2"), "--push-to-hub"], caplog)
    assert "HF_HUB_OFFLINE" in message and not (tmp_path / "o2").exists()


def _tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("where", ["the source", "inside the source", "a parent of the source"])
def test_overwrite_never_deletes_the_source(
    source: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture, where: str
) -> None:
    """A --root that is, is inside, or contains SRC is refused before anything is touched."""
    import shutil

    src = tmp_path / "copy" / "calvin"
    shutil.copytree(source, src)
    before = _tree(tmp_path / "copy")
    root = {"the source": src, "inside the source": src / "out", "a parent of the source": src.parent}[where]
    base = ["--repo-id", "local/x", "--image-format", "image", "--overwrite", "--split", "both"]
    message = _run_main([str(src), *base, "--root", str(root)], caplog)
    assert "--root" in message and "choose an --root outside" in message
    assert _tree(tmp_path / "copy") == before


@pytest.mark.parametrize(("key", "value"), [("robot_obs", np.inf), ("rel_actions", np.nan)])
def test_non_finite_values_are_refused_naming_file_and_key(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, key: str, value: float
) -> None:
    src = tmp_path / "src"
    write_native_split(src / "training", [(0, 19)], (), None, static=64, gripper=64)
    path = src / "training" / frame_filename(7)
    with np.load(path) as npz:
        arrays = dict(npz)
    arrays[key] = arrays[key].copy()
    arrays[key][2] = value
    np.savez_compressed(path, **arrays)
    argv = [str(src), "--repo-id", "local/x", "--mode", "all", "--image-format", "image"]
    message = _run_main([*argv, "--root", str(tmp_path / "o")], caplog)
    assert f"episode_0000007.npz: key {key!r} holds {value}" in message and "non-finite" in message
    assert not (tmp_path / "o").exists()


def test_corrupt_frame_mid_conversion_leaves_nothing_complete(tmp_path: Path, caplog) -> None:
    src = tmp_path / "src"
    write_native_split(src / "training", [(0, 19), (30, 49)], (), None, static=64, gripper=64)
    (src / "training" / frame_filename(35)).write_bytes(b"garbage")  # inside a segment: not checked up front
    argv = [
        str(src),
        "--repo-id",
        "local/x",
        "--mode",
        "all",
        "--image-format",
        "image",
        "--root",
        str(tmp_path / "o"),
    ]
    message = _run_main([*argv, "--episodes-per-part", "1"], caplog)
    assert "episode_0000035.npz: corrupt npz" in message
    assert not (tmp_path / "o").exists() and (tmp_path / "o.partial" / "parts" / "part-000000").is_dir()
    message = _run_main([*argv, "--episodes-per-part", "1"], caplog)
    assert "pass --resume" in message
    message = _run_main([*argv, "--episodes-per-part", "2", "--resume"], caplog)
    assert "different options (episodes_per_part)" in message


def _dataset_arrays(dataset) -> dict[str, np.ndarray]:
    table = dataset.hf_dataset.with_format("numpy")
    keys = [
        "observation.state",
        "observation.state_history",
        "observation.subgoal_trace",
        "action",
        "observation.environment_state",
        "calvin_frame_index",
        "episode_index",
        "index",
        "task_index",
    ]
    keys += ["observation.images.static", "observation.images.gripper"]  # PNG frames decoded by datasets
    return {key: np.asarray(table[key]) for key in keys}


def test_kill_and_resume_gives_identical_dataset(tmp_path: Path) -> None:
    src = tmp_path / "src"
    segments = [(i * 30, i * 30 + 19) for i in range(8)]
    write_native_split(src / "training", segments, (), None, static=64, gripper=64)
    root = tmp_path / "killed"
    argv = [
        sys.executable,
        "-m",
        "lerobot_subgoalvla.datasets_conversion.convert_calvin",
        str(src),
        "--repo-id",
        "local/k",
        "--root",
        str(root),
        "--mode",
        "all",
        "--image-format",
        "image",
        "--episodes-per-part",
        "1",
    ]
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "PYTHONPATH": os.pathsep.join(sys.path)}
    process = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    parts = root.with_name("killed.partial") / "parts"
    deadline = time.monotonic() + 300
    while not (parts / "part-000002").is_dir() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert not root.exists(), "the conversion finished before it could be killed"
    finished = sorted(p.name for p in parts.iterdir() if not p.name.endswith(".tmp"))
    assert 3 <= len(finished) < 8
    options = ConversionOptions(image_format="image", mode="all")
    resumed = convert(src, "local/k", root, options=options, episodes_per_part=1, resume=True)["training"]
    reference = convert(src, "local/k", tmp_path / "reference", options=options, episodes_per_part=1)[
        "training"
    ]
    got, want = _dataset_arrays(resumed), _dataset_arrays(reference)
    assert resumed.num_episodes == 8 and resumed.num_frames == 8 * 20
    for key in want:
        np.testing.assert_array_equal(got[key], want[key], err_msg=key)
    again = convert(src, "local/k", root, options=options, episodes_per_part=1, resume=True)["training"]
    assert again.num_frames == resumed.num_frames  # --resume on a complete ROOT returns it unchanged


@pytest.mark.slow
def test_parallel_workers_give_the_same_dataset(source: Path, tmp_path: Path) -> None:
    options = ConversionOptions(image_format="image", mode="all")
    serial = convert(source, "local/s", tmp_path / "serial", options=options, episodes_per_part=1)["training"]
    parallel = convert(
        source, "local/p", tmp_path / "parallel", options=options, episodes_per_part=1, workers=2
    )
    got, want = _dataset_arrays(parallel["training"]), _dataset_arrays(serial)
    for key in want:
        np.testing.assert_array_equal(got[key], want[key], err_msg=key)


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--episodes-per-part", "0"], "--episodes-per-part must be >= 1"),
        (["--max-episodes", "0"], "--max-episodes"),
    ],
)
def test_part_and_episode_counts_must_be_positive(
    source: Path, tmp_path: Path, caplog, flags, message
) -> None:
    argv = [
        str(source),
        "--repo-id",
        "local/x",
        "--image-format",
        "image",
        "--root",
        str(tmp_path / "o"),
        *flags,
    ]
    assert message in _run_main(argv, caplog)
    assert not (tmp_path / "o").exists() and not (tmp_path / "o.partial").exists()


def test_frames_of_different_image_sizes_name_the_file(tmp_path: Path, caplog) -> None:
    src = tmp_path / "src"
    write_native_split(src / "training", [(0, 9)], (), None, static=64, gripper=64)
    path = src / "training" / frame_filename(4)
    with np.load(path) as npz:
        arrays = dict(npz)
    arrays["rgb_static"] = np.zeros((32, 32, 3), dtype=np.uint8)
    np.savez_compressed(path, **arrays)
    argv = [str(src), "--repo-id", "local/x", "--mode", "all", "--image-format", "image"]
    message = _run_main([*argv, "--root", str(tmp_path / "o")], caplog)
    assert "episode_0000004.npz: 'rgb_static' is (32, 32, 3)" in message and "same image sizes" in message


def _with_segment_table(source: Path, tmp_path: Path, table: np.ndarray) -> Path:
    """A copy of the fixture's training split whose ep_start_end_ids.npy is ``table``."""
    import shutil

    src = tmp_path / "src"
    shutil.copytree(source / "training", src / "training")
    np.save(src / "training" / "ep_start_end_ids.npy", table)
    return src


@pytest.mark.parametrize(
    ("make_source", "flags", "message"),
    [
        (
            lambda s, t: (t / "a_file").write_text("x") and t / "a_file",
            [],
            "is a file, not a folder; point SRC",
        ),
        (lambda s, t: (t / "empty").mkdir() or t / "empty", [], "empty/training: split folder not found"),
        (lambda s, t: _with_segment_table(s, t, np.array([[0.0, 29.5]])), [], "holds float64 values"),
        (lambda s, t: _with_segment_table(s, t, np.array([[-3, 29]])), [], "row 0 [-3, 29] has a negative"),
        (
            lambda s, t: _with_segment_table(s, t, np.array([[40, 74], [0, 29], [20, 35]])),
            [],
            "rows 1 [0, 29] and 2 [20, 35] overlap",
        ),
        (
            lambda s, t: _with_segment_table(s, t, np.array([[0, 29], [40, 80]])),
            [],
            "episode_0000075.npz: frame file missing although ep_start_end_ids.npy covers it",
        ),
        (lambda s, t: s, ["--workers", "0"], "--workers must be >= 1, got 0"),
        (lambda s, t: s, ["--workers", "-2"], "--workers must be >= 1, got -2"),
        (lambda s, t: s, ["--workers", "two"], "argument --workers: invalid int value: 'two'"),
        (lambda s, t: s, ["--repo-id", ""], "--repo-id '' is not a dataset id"),
        (lambda s, t: s, ["--repo-id", "a/b/c"], "--repo-id 'a/b/c' is not a dataset id"),
        (lambda s, t: s, ["--repo-id", "/etc"], "--repo-id '/etc' is not a dataset id"),
        (lambda s, t: s, ["--repo-id", "me/my data"], "use NAMESPACE/NAME"),
    ],
    ids=[
        "src-is-a-file",
        "src-empty-folder",
        "table-float-ids",
        "table-negative-id",
        "table-rows-overlap",
        "table-points-at-missing-frames",
        "workers-0",
        "workers-negative",
        "workers-not-a-number",
        "repo-id-empty",
        "repo-id-three-parts",
        "repo-id-absolute-path",
        "repo-id-space",
    ],
)
def test_bad_source_table_or_flag_is_one_line_before_anything_is_written(
    source: Path, tmp_path: Path, caplog, make_source, flags: list[str], message: str
) -> None:
    """--repo-id matters with --root too: without it the id is the folder under $HF_LEROBOT_HOME, so '' or
    '/etc' would aim --overwrite at that folder itself or outside it."""
    src = make_source(source, tmp_path)
    argv = [str(src), "--repo-id", "local/x", "--mode", "all", "--image-format", "image"]
    got = _run_main([*argv, "--root", str(tmp_path / "o"), *flags], caplog)
    assert message in got
    assert not (tmp_path / "o").exists() and not (tmp_path / "o.partial").exists()


def test_segment_rows_out_of_order_convert_in_the_table_order(source: Path, tmp_path: Path) -> None:
    """Not an error: each episode is still its own segment's frames, in the order the table lists them."""
    src = _with_segment_table(source, tmp_path, np.array([[40, 74], [0, 29]]))
    options = ConversionOptions(image_format="image", mode="all")
    dataset = convert(src, "local/o", tmp_path / "o", options=options)["training"]
    frame_ids = _columns(dataset, "calvin_frame_index").reshape(-1)
    np.testing.assert_array_equal(frame_ids, np.r_[np.arange(40, 75), np.arange(0, 30)])
    np.testing.assert_array_equal(np.bincount(_columns(dataset, "episode_index")), [35, 30])
