"""The two-stage learning-rate schedule and the proprioceptive normaliser (continuous angles, exact
inverse)."""

from __future__ import annotations

import math

import pytest
import torch

from lerobot_subgoalvla.policies.subgoalvla.proprio_normalization import ProprioNormalizerProcessorStep
from lerobot_subgoalvla.policies.subgoalvla.schedule import (
    TwoStageCosineSchedulerConfig,
    warmup_cosine_factor,
)


def test_one_stage_is_plain_warmup_and_cosine() -> None:
    assert TwoStageCosineSchedulerConfig(stage2_start_step=None).phases(100) == [(0, 100)]
    assert warmup_cosine_factor(0, 100, 0.1, 0.01) == pytest.approx(0.1)
    assert warmup_cosine_factor(9, 100, 0.1, 0.01) == pytest.approx(1.0)
    assert warmup_cosine_factor(99, 100, 0.1, 0.01) == pytest.approx(0.01, abs=1e-3)


def test_switch_outside_the_run_keeps_one_stage() -> None:
    assert TwoStageCosineSchedulerConfig(stage2_start_step=500).phases(100) == [(0, 100)]
    assert TwoStageCosineSchedulerConfig(stage2_start_step=60).phases(100) == [(0, 60), (60, 40)]


def _step(**kwargs) -> ProprioNormalizerProcessorStep:
    mean, std = torch.linspace(-1, 1, 15), torch.linspace(0.5, 2, 15)
    return ProprioNormalizerProcessorStep.from_stats(
        {"mean": mean, "std": std}, (3, 4, 5), (math.pi, 0, 0), 1.0
    )


def test_decode_inverts_encode_and_angles_wrap_continuously() -> None:
    step = _step()
    raw = torch.randn(4, 8, 15)
    raw[..., 3] = torch.tensor([math.pi - 0.05, -math.pi + 0.05, 3.0, -3.0]).view(4, 1)
    encoded = step.encode(raw)
    torch.testing.assert_close(step.decode(encoded), raw, atol=1e-5, rtol=1e-5)
    assert float((encoded[0, 0, 3] - encoded[1, 0, 3]).abs()) == pytest.approx(0.1, abs=1e-5)
    assert encoded[..., 3].abs().max() < 0.2  # all four rolls are within 0.15 rad of pointing down


def test_statistics_survive_save_and_load() -> None:
    step = _step()
    fresh = ProprioNormalizerProcessorStep(**step.get_config())
    fresh.load_state_dict(step.state_dict())
    raw = torch.randn(3, 15)
    torch.testing.assert_close(fresh.encode(raw), step.encode(raw))


def test_a_step_without_statistics_says_how_to_get_them() -> None:
    step = ProprioNormalizerProcessorStep.from_stats(None, (3, 4, 5), (math.pi, 0, 0), 1.0)
    with pytest.raises(ValueError, match="policy_preprocessor.json"):
        step.encode(torch.zeros(2, 15))
