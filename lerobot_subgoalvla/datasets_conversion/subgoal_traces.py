"""Proprioceptive state histories and subgoal traces: the single source of truth for both.

SubgoalVLA (paper appendix A) conditions on a short history of proprioceptive states and trains its
planner head to predict a *subgoal trace*: the proprioceptive states a fixed number of steps into the
future. Both are pure windows over an episode's ``robot_obs`` (CALVIN spec 1.4), computed here once
so that the converter (offline), the policy (online, :class:`StateHistoryBuffer`) and the tests agree.

Definitions (per episode of ``T`` frames, frame index ``t``)::

    state_history[t, k]  = robot_obs[clamp(t - (L_h - 1) + k, 0, T - 1)]        k = 0 .. L_h - 1
    subgoal_trace[t, k]  = robot_obs[clamp(t + start + k, 0, T - 1)]             k = 0 .. L_s - 1

The history is oldest first and its last row is the current state; before the episode's first frame it
repeats the first frame. The trace clamps to the episode's last frame (the robot "stays" at its final
state), as the paper does for windows that run past the end of a demonstration.

Dimension legend:
    T    frames in one episode
    L_h  history length (default 15: robot_obs[t-14 .. t])
    L_s  trace length (default 8: robot_obs[t+14 .. t+21])
    B    batch (parallel environments at inference)
    P    proprioceptive dimension (15 for CALVIN's robot_obs)
"""

from __future__ import annotations

import numpy as np
import torch

#: Defaults of the data contract (team brief / DESIGN.md "Data contract"; paper appendix A).
DEFAULT_HISTORY_LENGTH = 15
DEFAULT_TRACE_START = 14
DEFAULT_TRACE_LENGTH = 8


def _check_positive(name: str, value: int) -> None:
    if not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")


def _gather_windows[ArrayT: (np.ndarray, torch.Tensor)](robot_obs: ArrayT, offsets: np.ndarray) -> ArrayT:
    """Gather ``robot_obs[clamp(t + offsets[k], 0, T-1)]`` for all t and k.

    Args:
        robot_obs: (T, P) states of ONE episode, numpy array or torch tensor.
        offsets: (K,) integer offsets relative to t.

    Returns:
        (T, K, P) array of the same type, dtype and device as ``robot_obs``.
    """
    if robot_obs.ndim != 2:
        raise ValueError(
            f"robot_obs must be a (T, P) array of one episode, got shape {tuple(robot_obs.shape)}"
        )
    num_frames = robot_obs.shape[0]
    if num_frames == 0:
        raise ValueError("robot_obs is empty: an episode needs at least one frame")
    indices = np.clip(np.arange(num_frames)[:, None] + offsets[None, :], 0, num_frames - 1)  # (T, K)
    if isinstance(robot_obs, torch.Tensor):
        return robot_obs[torch.as_tensor(indices, device=robot_obs.device)]  # (T, K, P)
    return robot_obs[indices]  # (T, K, P)


def state_history[ArrayT: (np.ndarray, torch.Tensor)](
    robot_obs: ArrayT, length: int = DEFAULT_HISTORY_LENGTH
) -> ArrayT:
    """The last ``length`` states of every frame, oldest first, clamped to the episode's first frame.

    Args:
        robot_obs: (T, P) proprioceptive states of one episode.
        length: L_h, number of states in the history (including the current one).

    Returns:
        (T, L_h, P): ``out[t, -1] == robot_obs[t]``; ``out[0]`` is ``robot_obs[0]`` repeated.
    """
    _check_positive("length", length)
    return _gather_windows(robot_obs, np.arange(-(length - 1), 1))


def subgoal_traces[ArrayT: (np.ndarray, torch.Tensor)](
    robot_obs: ArrayT, start: int = DEFAULT_TRACE_START, length: int = DEFAULT_TRACE_LENGTH
) -> ArrayT:
    """The future states ``robot_obs[t+start .. t+start+length-1]`` of every frame, clamped to the last frame.

    Args:
        robot_obs: (T, P) proprioceptive states of one episode.
        start: offset of the first trace state from t (>= 0; 14 in the paper's CALVIN setup).
        length: L_s, number of states in the trace.

    Returns:
        (T, L_s, P) subgoal traces.
    """
    if not isinstance(start, (int, np.integer)) or start < 0:
        raise ValueError(f"start must be a non-negative integer, got {start!r}")
    _check_positive("length", length)
    return _gather_windows(robot_obs, np.arange(start, start + length))


class StateHistoryBuffer:
    """Online counterpart of :func:`state_history` for a policy stepping B environments.

    The first :meth:`push` after construction or :meth:`reset` fills the history with the pushed state
    (the same first-frame clamping as the offline definition), so the policy sees at inference exactly
    what it saw in training.
    """

    def __init__(self, length: int = DEFAULT_HISTORY_LENGTH) -> None:
        """Args:
        length: L_h, number of states returned by :meth:`push` (including the newest).
        """
        _check_positive("length", length)
        self.length = int(length)
        self._history: torch.Tensor | None = None  # (B, L_h, P)
        self._fresh: torch.Tensor | None = None  # (B,) rows to refill at the next push

    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Forget the history of all environments, or of those where ``mask`` (B,) is True.

        Args:
            mask: optional (B,) bool tensor of environments that start a new episode (vector envs
                reset independently); None resets everything.
        """
        if mask is None or self._history is None:
            self._history = None
            self._fresh = None
            return
        mask = torch.as_tensor(mask, dtype=torch.bool, device=self._history.device)
        if mask.shape != (self._history.shape[0],):
            raise ValueError(
                f"reset mask must have shape ({self._history.shape[0]},), got {tuple(mask.shape)}"
            )
        self._fresh = self._fresh | mask

    def push(self, state: torch.Tensor) -> torch.Tensor:
        """Append the newest state and return the history.

        Args:
            state: (B, P) current proprioceptive states.

        Returns:
            (B, L_h, P) history, oldest first; the last row is ``state``.
        """
        if state.ndim != 2:
            raise ValueError(f"state must have shape (B, P), got {tuple(state.shape)}")
        repeated = state[:, None, :].expand(-1, self.length, -1)  # (B, L_h, P)
        if self._history is None:
            self._history = repeated.clone()
        elif self._history.shape[0] != state.shape[0] or self._history.shape[2] != state.shape[1]:
            raise ValueError(
                f"state shape {tuple(state.shape)} does not match the buffered history "
                f"{tuple(self._history.shape)}; call reset() when the number of environments changes"
            )
        else:
            history = torch.cat([self._history[:, 1:].to(state), state[:, None, :]], dim=1)  # (B, L_h, P)
            self._history = torch.where(self._fresh[:, None, None], repeated, history)
        self._fresh = torch.zeros(state.shape[0], dtype=torch.bool, device=state.device)
        return self._history.clone()
