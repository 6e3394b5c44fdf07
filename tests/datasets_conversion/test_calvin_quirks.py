"""CALVIN quirks: block slot order per scene, window clamping/dropping/overlap, ALL-mode task labels."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_subgoalvla.datasets_conversion.calvin_format import LanguageAnnotations
from lerobot_subgoalvla.datasets_conversion.calvin_quirks import (
    PLAY_TASK,
    block_order_of,
    canonicalize_scene_obs,
    language_episodes,
    play_episodes,
)


def _scene_obs_with_slots(values: tuple[float, float, float]) -> np.ndarray:
    obs = np.arange(24, dtype=np.float64)[None].repeat(2, axis=0)  # (F=2, 24)
    for slot, value in enumerate(values):
        obs[:, 6 + 6 * slot : 12 + 6 * slot] = value
    return obs


@pytest.mark.parametrize(
    ("scene", "colors_in_slots"),
    [
        ("calvin_scene_A", ("pink", "blue", "red")),
        ("calvin_scene_B", ("red", "blue", "pink")),
        ("calvin_scene_C", ("blue", "red", "pink")),
        ("calvin_scene_D", ("red", "blue", "pink")),
    ],
)
def test_canonical_block_order(scene: str, colors_in_slots: tuple[str, ...]) -> None:
    code = {"red": 100.0, "blue": 200.0, "pink": 300.0}
    obs = _scene_obs_with_slots(tuple(code[c] for c in colors_in_slots))
    out = canonicalize_scene_obs(obs, block_order_of(scene))
    np.testing.assert_array_equal(out[:, :6], obs[:, :6])  # doors/button/switch/lights untouched
    for slot, color in enumerate(("red", "blue", "pink")):
        assert (out[:, 6 + 6 * slot : 12 + 6 * slot] == code[color]).all()


def test_unknown_scene_names_the_known_ones() -> None:
    with pytest.raises(ValueError, match="calvin_scene_A"):
        block_order_of("calvin_scene_E")


SEGMENTS = np.array([[0, 29], [40, 59]])


def test_windows_overlap_clamp_and_drop() -> None:
    ann = LanguageAnnotations(
        np.array([[0, 10], [5, 20], [25, 45], [31, 35], [50, 80], [9, 3]]),
        ["a", "b", "c", "stray", "d", "bad"],
        ["open_drawer"] * 6,
    )
    episodes, report = language_episodes(SEGMENTS, ann)
    assert [(e.start, e.end) for e in episodes] == [(0, 10), (5, 20), (25, 29), (50, 59)]
    assert [e.tasks[0] for e in episodes] == ["a", "b", "c", "d"]
    assert [e.segment for e in episodes] == [0, 0, 0, 1]
    assert episodes[2].length == 5 and len(episodes[2].tasks) == 5
    assert (report.kept, report.clamped, report.dropped_stray, report.dropped_invalid) == (4, 2, 1, 1)


def test_play_episodes_label_frames_with_latest_window() -> None:
    ann = LanguageAnnotations(np.array([[2, 6], [5, 8], [25, 45]]), ["a", "b", "c"], ["open_drawer"] * 3)
    episodes = play_episodes(SEGMENTS, ann)
    assert [(e.start, e.end) for e in episodes] == [(0, 29), (40, 59)]
    tasks = episodes[0].tasks
    assert tasks[:2] == (PLAY_TASK, PLAY_TASK)
    assert tasks[2:5] == ("a",) * 3 and tasks[5:9] == ("b",) * 4
    assert tasks[25:30] == ("c",) * 5 and tasks[9] == PLAY_TASK
    assert episodes[1].tasks == (PLAY_TASK,) * 20
    assert play_episodes(SEGMENTS, None)[0].tasks == (PLAY_TASK,) * 30
