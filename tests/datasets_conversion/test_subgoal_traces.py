"""Semantics of the state history / subgoal trace windows (data contract) and the online buffer."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lerobot_subgoalvla.datasets_conversion.subgoal_traces import (
    StateHistoryBuffer,
    state_history,
    subgoal_traces,
)


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


def test_torch_input_matches_numpy() -> None:
    obs = _ramp(25)
    tobs = torch.from_numpy(obs).double()
    hist_t = state_history(tobs, length=6)
    trace_t = subgoal_traces(tobs, start=2, length=4)
    assert isinstance(hist_t, torch.Tensor) and hist_t.dtype == torch.float64
    np.testing.assert_array_equal(hist_t.numpy(), state_history(obs, length=6).astype(np.float64))
    np.testing.assert_array_equal(trace_t.numpy(), subgoal_traces(obs, start=2, length=4).astype(np.float64))


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: state_history(np.zeros((5, 15)), length=0), "length"),
        (lambda: subgoal_traces(np.zeros((5, 15)), start=-1), "start"),
        (lambda: subgoal_traces(np.zeros((5, 2, 15))), r"\(T, P\)"),
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


def test_buffer_output_is_not_aliased() -> None:
    buffer = StateHistoryBuffer(length=2)
    first = buffer.push(torch.zeros(1, 3))
    buffer.push(torch.ones(1, 3))
    assert torch.count_nonzero(first) == 0
