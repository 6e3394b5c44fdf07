"""Native CALVIN format: writer/reader round-trip and validator errors (one line naming file and fix)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from native_fixtures import synthetic_frame, write_native_split

from lerobot_subgoalvla.datasets_conversion.calvin_format import (
    ALL_KEYS,
    CalvinSplit,
    LanguageAnnotations,
    frame_filename,
    write_frame,
    write_language,
    write_segments,
)
from lerobot_subgoalvla.datasets_conversion.calvin_validate import validate_split

WINDOWS = [(0, 9, "open the drawer", "open_drawer"), (12, 25, "press the button", "turn_on_led")]


@pytest.fixture
def split_dir(tmp_path: Path) -> Path:
    return write_native_split(
        tmp_path / "training", [(0, 14), (20, 29)], WINDOWS, {"calvin_scene_B": (0, 29)}, static=16, gripper=8
    )


def test_frame_filename_is_seven_digits() -> None:
    assert frame_filename(42) == "episode_0000042.npz"
    assert frame_filename(1795044) == "episode_1795044.npz"


def test_round_trip(split_dir: Path) -> None:
    split = CalvinSplit(split_dir)
    np.testing.assert_array_equal(split.segments, [[0, 14], [20, 29]])
    np.testing.assert_array_equal(np.load(split_dir / "ep_lens.npy"), [15, 10])
    assert split.scene_info == {"calvin_scene_B": (0, 29)}
    assert split.scene_of(25) == "calvin_scene_B"
    assert split.num_frames == 25
    frames = split.load_frames([20, 21, 22])
    assert frames["robot_obs"].shape == (3, 15) and frames["robot_obs"].dtype == np.float64
    np.testing.assert_array_equal(frames["robot_obs"][:, 0], [20, 21, 22])
    assert frames["rgb_static"].shape == (3, 16, 16, 3) and frames["rgb_gripper"].dtype == np.uint8
    lang = split.language()
    np.testing.assert_array_equal(lang.indx, [[0, 9], [12, 25]])
    assert lang.ann == ["open the drawer", "press the button"] and lang.task == ["open_drawer", "turn_on_led"]
    assert lang.emb is None
    stats = split.statistics()
    assert len(stats["robot_obs"][0]["mean"]) == 15 and len(stats["act_max_bound"]) == 7


def test_language_round_trip_with_embeddings_and_calvin_layout(tmp_path: Path) -> None:
    emb = np.random.default_rng(0).normal(size=(2, 1, 384)).astype(np.float32)
    write_language(
        tmp_path,
        LanguageAnnotations(np.array([[0, 64], [5, 40]]), ["a", "b"], ["open_drawer", "stack_block"], emb),
    )
    raw = np.load(tmp_path / "lang_annotations" / "auto_lang_ann.npy", allow_pickle=True).item()
    assert raw["info"]["indx"] == [(0, 64), (5, 40)] and raw["info"]["episodes"] == []
    assert raw["language"]["emb"].shape == (2, 1, 384)
    back = LanguageAnnotations.from_dict(raw)
    np.testing.assert_array_equal(back.emb, emb)


def test_validator_accepts_good_split_and_ignores_stray_ids(tmp_path: Path) -> None:
    split_dir = write_native_split(
        tmp_path / "validation", [(3, 10)], WINDOWS[:1], static=8, gripper=8, stray_ids=[50]
    )
    split = validate_split(split_dir, require_language=True)
    assert split.scene_info == {"calvin_scene_D": (3, 10)}  # validation: scene D without scene_info.npy
    assert split.num_frames == 8


def _corrupt(path: Path) -> None:
    path.write_bytes(b"PK\x03\x04 not really a zip")


def _drop_key(path: Path) -> None:
    arrays = dict(np.load(path))
    arrays.pop("rel_actions")
    write_frame(path.parent, int(path.stem.split("_")[1]), arrays)


def _bad_shape(path: Path) -> None:
    arrays = dict(np.load(path))
    arrays["robot_obs"] = np.zeros(14)
    write_frame(path.parent, int(path.stem.split("_")[1]), arrays)


def _bad_dtype(path: Path) -> None:
    arrays = dict(np.load(path))
    arrays["rgb_static"] = arrays["rgb_static"].astype(np.float32)
    write_frame(path.parent, int(path.stem.split("_")[1]), arrays)


@pytest.mark.parametrize(
    ("breaker", "error", "match"),
    [
        (_corrupt, ValueError, r"episode_0000020\.npz: corrupt npz.*re-download"),
        (_drop_key, ValueError, r"episode_0000020\.npz: missing key\(s\) \['rel_actions'\]"),
        (
            _bad_shape,
            ValueError,
            r"episode_0000020\.npz: key 'robot_obs' is float64 \(14,\), expected float \(15\)",
        ),
        (_bad_dtype, ValueError, r"episode_0000020\.npz: key 'rgb_static' is float32.*expected uint8"),
        (Path.unlink, FileNotFoundError, r"episode_0000020\.npz: frame file missing"),
    ],
)
def test_validator_frame_errors(split_dir: Path, breaker, error: type, match: str) -> None:
    breaker(split_dir / frame_filename(20))
    with pytest.raises(error, match=match) as info:
        validate_split(split_dir, require_language=False)
    assert "\n" not in str(info.value)


def test_validator_split_level_errors(split_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"nowhere/training: split folder not found"):
        validate_split(tmp_path / "nowhere" / "training", require_language=False)
    (split_dir / "lang_annotations" / "auto_lang_ann.npy").unlink()
    validate_split(split_dir, require_language=False)  # ALL mode does not need annotations
    with pytest.raises(
        FileNotFoundError, match=r"auto_lang_ann\.npy: language annotations not found.*--mode all"
    ):
        validate_split(split_dir, require_language=True)
    write_segments(split_dir, np.zeros((0, 2)))
    with pytest.raises(ValueError, match=r"ep_start_end_ids\.npy: empty split"):
        validate_split(split_dir, require_language=False)
    (split_dir / "ep_start_end_ids.npy").unlink()
    with pytest.raises(FileNotFoundError, match=r"ep_start_end_ids\.npy: segment table missing"):
        validate_split(split_dir, require_language=False)


def test_validator_full_native_profile_requires_all_ten_keys(split_dir: Path) -> None:
    with pytest.raises(ValueError, match="missing key"):
        validate_split(split_dir, require_language=False, keys=ALL_KEYS)
    rng = np.random.default_rng(1)
    frame = synthetic_frame(rng, 0, 8, 8)
    assert set(frame) < set(ALL_KEYS)


@pytest.mark.parametrize(
    ("ann", "task", "match"),
    [
        ([b"open the \xff\xfe drawer"], ["open_drawer"], "window 0: instruction .* is not UTF-8"),
        (["  "], ["open_drawer"], "window 0: empty or non-text instruction"),
        (["open the \udce9 drawer"], ["open_drawer"], "window 0: instruction .* is not valid Unicode"),
        (["open the drawer"], ["open_the_drawer"], "Unknown CALVIN task 'open_the_drawer'"),
        ([b"open the drawer"], [b"open_drawer"], None),  # UTF-8 bytes, as some exports store them: fine
    ],
)
def test_bad_annotations_are_refused_naming_the_file_and_window(tmp_path: Path, ann, task, match) -> None:
    layout = {"info": {"indx": [(0, 9)], "episodes": []}, "language": {"ann": ann, "task": task}}
    path = tmp_path / "lang_annotations" / "auto_lang_ann.npy"
    path.parent.mkdir(parents=True)
    np.save(path, layout, allow_pickle=True)
    write_segments(tmp_path, np.array([[0, 9]]))
    split = CalvinSplit(tmp_path)
    if match is None:
        assert split.language().ann == ["open the drawer"] and split.language().task == ["open_drawer"]
        return
    with pytest.raises(ValueError, match=f"auto_lang_ann.npy: {match}"):
        split.language()


def test_garbled_annotation_file_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "lang_annotations" / "auto_lang_ann.npy"
    path.parent.mkdir(parents=True)
    path.write_bytes(np.lib.format.magic(1, 0) + b"garbage that is not a pickle")
    write_segments(tmp_path, np.array([[0, 9]]))
    with pytest.raises(ValueError, match=r"auto_lang_ann.npy: unreadable .*; re-download this file"):
        CalvinSplit(tmp_path).language()
