"""The data contract: the history / trace window (offline), the policy's online buffer, the metadata."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lerobot_subgoalvla.contract.metadata import ProprioMetadata
from lerobot_subgoalvla.contract.window import TraceWindow
from lerobot_subgoalvla.policies.subgoalvla.state_history import StateHistoryBuffer


def state_history(states: np.ndarray, length: int = 15, stride: int = 1) -> np.ndarray:
    return TraceWindow(history_length=length, stride=stride).histories(states)


def subgoal_traces(states: np.ndarray, start: int = 14, length: int = 8, stride: int = 1) -> np.ndarray:
    return TraceWindow(trace_start=start, trace_length=length, stride=stride).traces(states)


def _ramp(num_frames: int, dim: int = 15) -> np.ndarray:
    """robot_obs whose row t is t everywhere plus a per-dimension offset, so indices are recoverable."""
    return np.arange(num_frames, dtype=np.float32)[:, None] + np.arange(dim, dtype=np.float32)[None, :] * 1000


def test_history_is_oldest_first_and_clamped_to_first_frame() -> None:
    obs = _ramp(20)
    hist = state_history(obs, length=15)
    assert hist.shape == (20, 15, 15)
    assert hist.dtype == np.float32
    np.testing.assert_array_equal(hist[:, -1], obs)  # last row == current state
    np.testing.assert_array_equal(hist[0], np.repeat(obs[:1], 15, axis=0))  # first frame repeated
    # frame 3: 11 copies of frame 0, then frames 0..3
    expected = [0] * 11 + [0, 1, 2, 3]
    np.testing.assert_array_equal(hist[3, :, 0], np.array(expected, dtype=np.float32))
    np.testing.assert_array_equal(hist[19, :, 0], np.arange(5, 20, dtype=np.float32))


def test_trace_offsets_and_clamped_to_last_frame() -> None:
    obs = _ramp(30)
    trace = subgoal_traces(obs, start=14, length=8)
    assert trace.shape == (30, 8, 15)
    np.testing.assert_array_equal(trace[0, :, 0], np.arange(14, 22, dtype=np.float32))
    np.testing.assert_array_equal(
        trace[10, :, 0], np.array([24, 25, 26, 27, 28, 29, 29, 29], dtype=np.float32)
    )
    np.testing.assert_array_equal(trace[29], np.repeat(obs[-1:], 8, axis=0))
    np.testing.assert_array_equal(trace[5, :, 3], obs[19:27, 3])


@pytest.mark.parametrize(("start", "length"), [(0, 1), (1, 3), (5, 10)])
def test_trace_options(start: int, length: int) -> None:
    obs = _ramp(12, dim=4)
    trace = subgoal_traces(obs, start=start, length=length)
    assert trace.shape == (12, length, 4)
    for t in range(12):
        idx = np.minimum(np.arange(t + start, t + start + length), 11)
        np.testing.assert_array_equal(trace[t], obs[idx])
    if start == 0:
        np.testing.assert_array_equal(trace[:, 0], obs)


def test_short_episode_shorter_than_windows() -> None:
    obs = _ramp(3)
    np.testing.assert_array_equal(subgoal_traces(obs)[0], np.repeat(obs[-1:], 8, axis=0))
    np.testing.assert_array_equal(state_history(obs)[2, :13], np.repeat(obs[:1], 13, axis=0))


def test_stride_spaces_history_and_trace_states() -> None:
    obs = _ramp(40, dim=2)
    window = TraceWindow(history_length=4, trace_start=5, trace_length=3, stride=3)
    np.testing.assert_array_equal(window.histories(obs)[20, :, 0], [11, 14, 17, 20])
    np.testing.assert_array_equal(window.traces(obs)[20, :, 0], [25, 28, 31])
    assert window.trace_end == 11 and window.history_span == 9


@pytest.mark.parametrize(("fps", "stride", "start"), [(30, 1, 14), (80, 3, 37), (10, 1, 5), (15, 1, 7)])
def test_window_keeps_the_papers_seconds_at_other_frame_rates(fps: float, stride: int, start: int) -> None:
    window = TraceWindow.for_fps(fps)
    assert (window.stride, window.trace_start, window.history_length, window.trace_length) == (
        stride,
        start,
        15,
        8,
    )


def test_metadata_round_trips_through_a_feature_dict() -> None:
    features = {"observation.subgoal_trace": {"dtype": "float32", "shape": (8, 4), "names": None}}
    metadata = ProprioMetadata(TraceWindow.for_fps(80), 80, (3,), (0.5,), ("open the drawer",), "tests")
    attached = metadata.attach(features)
    assert "info" not in features["observation.subgoal_trace"]  # the input is not changed
    assert ProprioMetadata.from_features(attached) == metadata
    assert ProprioMetadata.from_features(features) is None
    with pytest.raises(ValueError, match="index 3 is out of range"):
        metadata.check_state_dim(2, "--angle-dims")


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: state_history(np.zeros((5, 15)), length=0), "length"),
        (lambda: subgoal_traces(np.zeros((5, 15)), start=-1), "start"),
        (lambda: subgoal_traces(np.zeros((5, 2, 15))), r"\(T, p\)"),
        (lambda: state_history(np.zeros((0, 15))), "empty"),
    ],
)
def test_bad_arguments_raise(call, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        call()


def test_buffer_matches_offline_history() -> None:
    obs = _ramp(20, dim=5)
    batch = torch.stack([torch.from_numpy(obs), torch.from_numpy(obs) * 2], dim=0)  # (B=2, T, P)
    buffer = StateHistoryBuffer(length=7)
    offline = state_history(obs, length=7)
    for t in range(20):
        out = buffer.push(batch[:, t])
        assert out.shape == (2, 7, 5)
        np.testing.assert_array_equal(out[0].numpy(), offline[t])
        np.testing.assert_array_equal(out[1].numpy(), offline[t] * 2)


def test_buffer_reset_all_and_masked() -> None:
    buffer = StateHistoryBuffer(length=3)
    for value in (1.0, 2.0, 3.0):
        out = buffer.push(torch.full((2, 1), value))
    np.testing.assert_array_equal(out[:, :, 0].numpy(), [[1, 2, 3], [1, 2, 3]])
    buffer.reset(torch.tensor([False, True]))
    out = buffer.push(torch.full((2, 1), 9.0))
    np.testing.assert_array_equal(out[:, :, 0].numpy(), [[2, 3, 9], [9, 9, 9]])
    out = buffer.push(torch.full((2, 1), 10.0))
    np.testing.assert_array_equal(out[:, :, 0].numpy(), [[3, 9, 10], [9, 9, 10]])
    buffer.reset()
    out = buffer.push(torch.full((3, 1), 4.0))  # batch size may change after a full reset
    np.testing.assert_array_equal(out[:, :, 0].numpy(), np.full((3, 3), 4.0))
    with pytest.raises(ValueError, match="reset"):
        buffer.push(torch.zeros(2, 1))


@pytest.mark.parametrize("stride", [1, 3])
def test_strided_buffer_matches_offline_history(stride: int) -> None:
    obs = _ramp(30, dim=3)
    buffer = StateHistoryBuffer(length=5, stride=stride)
    offline = state_history(obs, length=5, stride=stride)
    for t in range(30):
        np.testing.assert_array_equal(buffer.push(torch.from_numpy(obs[None, t]))[0].numpy(), offline[t])


def test_buffer_output_is_not_aliased() -> None:
    buffer = StateHistoryBuffer(length=2)
    first = buffer.push(torch.zeros(1, 3))
    buffer.push(torch.ones(1, 3))
    assert torch.count_nonzero(first) == 0


def test_keys_are_lerobots_constants() -> None:
    from lerobot.utils import constants

    from lerobot_subgoalvla.contract import keys

    assert (keys.STATE_KEY, keys.ACTION_KEY, keys.ENV_STATE_KEY) == (
        constants.OBS_STATE,
        constants.ACTION,
        constants.OBS_ENV_STATE,
    )
    assert keys.SINGLE_IMAGE_KEY == constants.OBS_IMAGE and keys.IMAGES_PREFIX == constants.OBS_IMAGES + "."
    assert keys.OBS_PREFIX == constants.OBS_PREFIX
