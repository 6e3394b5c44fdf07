"""The state-history / subgoal-trace window: the one definition the converters, the policy and tests share.

SubgoalVLA (paper appendix A) conditions on a short history of proprioceptive states and trains its planner to
predict a *subgoal trace*: states a fixed time into the future. Both are windows over one episode's
``observation.state`` (per frame ``t`` of an episode of ``T`` frames, stride ``s``)::

    state_history[t, k] = state[clamp(t - (h - 1 - k) * s, 0, T - 1)]        k = 0 .. h - 1
    subgoal_trace[t, k] = state[clamp(t + start + k * s, 0, T - 1)]          k = 0 .. M - 1

The history is oldest first, its last row the current state, and before the episode's first frame it repeats
that frame; the trace clamps to the episode's last frame (the robot "stays" at its final state).

How the window scales with the frame rate (``TraceWindow.for_fps``): the paper's window is counted in frames
of CALVIN's 30 Hz control loop (h = 15, start = 14, M = 8: 0.47 s of history, a trace 0.47-0.70 s ahead). The
*number* of states (h, M) is part of the model (its query count), so it stays; the *time* the window spans is
what the method is about, so start and stride scale with the rate: ``stride = max(1, round(fps / 30))`` and
``start = max(1, round(14 * fps / 30))``. At 30 Hz that is exactly the paper's window; at 80 Hz (Meta-World)
stride 3 and start 37 (a history of 0.53 s, a trace 0.46-0.72 s ahead); at 10 Hz stride 1 and start 5 (the
trace cannot be denser than the data, so a 10 Hz history spans 1.4 s).

Dimension legend: ``T`` frames of one episode, ``h`` history states, ``M`` trace states, ``p`` state dim.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

#: CALVIN's control rate, at which the paper counts its window in frames (appendix A).
REFERENCE_FPS = 30
PAPER_HISTORY_LENGTH = 15
PAPER_TRACE_START = 14
PAPER_TRACE_LENGTH = 8


@dataclass(frozen=True)
class TraceWindow:
    """Which states form the history and the subgoal trace of a frame (module docstring).

    Args:
        history_length: h, states in ``observation.state_history`` (the current one included).
        trace_start: frames from t to the first trace state (>= 0).
        trace_length: M, states in ``observation.subgoal_trace``.
        stride: frames between consecutive states of the history and of the trace.
    """

    history_length: int = PAPER_HISTORY_LENGTH
    trace_start: int = PAPER_TRACE_START
    trace_length: int = PAPER_TRACE_LENGTH
    stride: int = 1

    def __post_init__(self) -> None:
        for name in ("history_length", "trace_length", "stride"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"trace window: {name} must be a positive integer, got {value!r}")
        if not isinstance(self.trace_start, (int, np.integer)) or self.trace_start < 0:
            raise ValueError(f"trace window: trace_start must be an integer >= 0, got {self.trace_start!r}")

    @classmethod
    def for_fps(
        cls,
        fps: float,
        history_length: int = PAPER_HISTORY_LENGTH,
        trace_length: int = PAPER_TRACE_LENGTH,
    ) -> TraceWindow:
        """The paper's window carried to ``fps`` frames per second (same time span, same state counts)."""
        if fps <= 0:
            raise ValueError(f"trace window: fps must be positive, got {fps!r}")
        stride = max(1, round(fps / REFERENCE_FPS))
        start = max(1, round(PAPER_TRACE_START * fps / REFERENCE_FPS))
        return cls(history_length, start, trace_length, stride)

    @property
    def trace_end(self) -> int:
        """Frames from t to the last trace state."""
        return self.trace_start + (self.trace_length - 1) * self.stride

    @property
    def history_span(self) -> int:
        """Frames from the oldest history state to t, i.e. states an online buffer must keep minus one."""
        return (self.history_length - 1) * self.stride

    def history_offsets(self) -> np.ndarray:
        """(h,) frame offsets of the history states relative to t, oldest first (the last is 0)."""
        return np.arange(-(self.history_length - 1), 1) * self.stride

    def trace_offsets(self) -> np.ndarray:
        """(M,) frame offsets of the trace states relative to t."""
        return self.trace_start + np.arange(self.trace_length) * self.stride

    def histories(self, states: np.ndarray) -> np.ndarray:
        """(T, p) states of one episode -> (T, h, p) histories (``out[t, -1] == states[t]``)."""
        return _gather(states, self.history_offsets())

    def traces(self, states: np.ndarray) -> np.ndarray:
        """(T, p) states of one episode -> (T, M, p) subgoal traces."""
        return _gather(states, self.trace_offsets())

    def to_dict(self) -> dict[str, int]:
        return {key: int(value) for key, value in asdict(self).items()}

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> TraceWindow:
        return cls(
            **{key: int(values[key]) for key in ("history_length", "trace_start", "trace_length", "stride")}
        )

    def describe(self) -> str:
        """One line for messages: ``h=15 start=14 M=8 stride=1``."""
        return f"h={self.history_length} start={self.trace_start} M={self.trace_length} stride={self.stride}"


def _gather(states: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """``states[clamp(t + offsets[k], 0, T - 1)]`` for every t and k: (T, p) -> (T, K, p)."""
    if states.ndim != 2:
        raise ValueError(f"states must be a (T, p) array of one episode, got shape {tuple(states.shape)}")
    num_frames = states.shape[0]
    if num_frames == 0:
        raise ValueError("states is empty: an episode needs at least one frame")
    indices = np.clip(np.arange(num_frames)[:, None] + offsets[None, :], 0, num_frames - 1)  # (T, K)
    return states[indices]
