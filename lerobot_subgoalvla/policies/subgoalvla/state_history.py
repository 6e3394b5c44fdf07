"""The policy's online state history: ``observation.state_history`` rebuilt at inference, step by step.

The dataset's column is ``contract.window.TraceWindow.histories`` of each episode; this buffer gives the
policy exactly that at inference for B environments stepping in lockstep: h states ``stride`` frames apart,
oldest first, the newest last, and before an episode's first frame that frame repeated.

Dimension legend (the package's, ``__init__.py``): ``B`` parallel envs, ``h`` history states, ``p`` state dim;
the buffer keeps (h - 1) * stride + 1 states.
"""

from __future__ import annotations

import torch
from torch import Tensor

from lerobot_subgoalvla.contract.window import TraceWindow


class StateHistoryBuffer:
    """The last ``(length - 1) * stride + 1`` states of B envs; :meth:`push` returns every ``stride``-th.

    The first :meth:`push` after construction or :meth:`reset` fills the buffer with the pushed state (the
    dataset's first-frame clamping), so the policy sees at inference what it saw in training.

    Args:
        length: h, states returned by :meth:`push` (the newest included).
        stride: frames between consecutive returned states.
    """

    def __init__(self, length: int, stride: int = 1) -> None:
        window = TraceWindow(history_length=length, stride=stride)  # validates both
        self.length, self.stride = window.history_length, window.stride
        self._kept = window.history_span + 1
        self._states: Tensor | None = None  # (B, kept, p), oldest first
        self._fresh: Tensor | None = None  # (B,) envs to refill at the next push

    def reset(self, mask: Tensor | None = None) -> None:
        """Forget the history of all envs, or of those where ``mask`` (B,) is True (a new episode)."""
        if mask is None or self._states is None:
            self._states = None
            self._fresh = None
            return
        mask = torch.as_tensor(mask, dtype=torch.bool, device=self._states.device)
        if mask.shape != (self._states.shape[0],):
            raise ValueError(
                f"reset mask must have shape ({self._states.shape[0]},), got {tuple(mask.shape)}"
            )
        self._fresh = self._fresh | mask

    def push(self, state: Tensor) -> Tensor:
        """Append the newest states (B, p) and return the history (B, h, p), oldest first."""
        if state.ndim != 2:
            raise ValueError(f"state must have shape (B, p), got {tuple(state.shape)}")
        repeated = state[:, None, :].expand(-1, self._kept, -1)  # (B, kept, p)
        if self._states is None:
            self._states = repeated.clone()
        elif self._states.shape[0] != state.shape[0] or self._states.shape[2] != state.shape[1]:
            raise ValueError(
                f"state shape {tuple(state.shape)} does not match the buffered history "
                f"{tuple(self._states.shape)}; call reset() when the number of environments changes"
            )
        else:
            shifted = torch.cat([self._states[:, 1:].to(state), state[:, None, :]], dim=1)  # (B, kept, p)
            self._states = torch.where(self._fresh[:, None, None], repeated, shifted)
        self._fresh = torch.zeros(state.shape[0], dtype=torch.bool, device=state.device)
        return self._states[:, :: self.stride].clone()  # (B, h, p)
