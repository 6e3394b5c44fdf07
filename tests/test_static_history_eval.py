"""The static-history probe: the buffer it patches returns the newest state repeated at every step."""

from __future__ import annotations

import pytest
import torch
from helpers.study import study_module

from lerobot_subgoalvla.policies.subgoalvla.state_history import StateHistoryBuffer


@pytest.fixture
def probe(monkeypatch: pytest.MonkeyPatch):
    yield from study_module(monkeypatch, "static_history_eval")


def test_the_history_is_the_newest_state_repeated(probe, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(StateHistoryBuffer, "push", probe.static_push(StateHistoryBuffer.push))
    buffer = StateHistoryBuffer(length=3, stride=2)
    for step in range(4):
        state = torch.full((2, 4), float(step))
        history = buffer.push(state)
        assert history.shape == (2, 3, 4)
        assert torch.equal(history, state[:, None].expand(-1, 3, -1))


def test_unpatched_the_history_moves(probe) -> None:
    buffer = StateHistoryBuffer(length=3, stride=1)
    for step in range(3):
        history = buffer.push(torch.full((1, 2), float(step)))
    assert history[0, :, 0].tolist() == [0.0, 1.0, 2.0]
