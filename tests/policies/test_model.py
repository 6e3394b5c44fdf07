"""SubgoalVLAModel: two-stage losses, gradient routing, sampling, ablations (tiny preset, CPU)."""

from __future__ import annotations

import pytest
import torch
from helpers.vocabulary import CALVIN_WORDS, calvin_backbone
from lerobot.configs import FeatureType, PolicyFeature
from lerobot.utils.constants import OBS_LANGUAGE_ATTENTION_MASK, OBS_LANGUAGE_TOKENS

from lerobot_subgoalvla.policies.subgoalvla.backbone import tokenize_instructions
from lerobot_subgoalvla.policies.subgoalvla.configuration_subgoalvla import SubgoalVLAConfig
from lerobot_subgoalvla.policies.subgoalvla.model import SubgoalVLAModel
from lerobot_subgoalvla.policies.subgoalvla.tokenizer import build_tiny_tokenizer

P, A, H, M, N = 15, 7, 15, 8, 15


def make_config(**overrides: object) -> SubgoalVLAConfig:
    features = {
        "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(P,)),
        "observation.images.static": PolicyFeature(type=FeatureType.VISUAL, shape=(3, 64, 64)),
        "observation.images.gripper": PolicyFeature(type=FeatureType.VISUAL, shape=(3, 32, 32)),
    }
    config = SubgoalVLAConfig(
        preset="tiny",
        backbone=calvin_backbone(),
        input_features=features,
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(A,))},
        **overrides,
    )
    config.planner.repeated_diffusion_steps = 2
    config.generator.repeated_diffusion_steps = 2
    return config


def make_batch(model: SubgoalVLAModel, batch_size: int = 2) -> dict[str, torch.Tensor]:
    instructions = ["open the drawer", "lift the red block from the sliding cabinet"][:batch_size]
    ids, mask = tokenize_instructions(
        build_tiny_tokenizer(CALVIN_WORDS), instructions, 12, model.backbone.input_spec
    )
    is_pad = torch.zeros(batch_size, N, dtype=torch.bool)
    is_pad[0, -3:] = True
    return {
        "observation.images.static": torch.rand(batch_size, 3, 64, 64),
        "observation.images.gripper": torch.rand(batch_size, 3, 32, 32),
        OBS_LANGUAGE_TOKENS: ids,
        OBS_LANGUAGE_ATTENTION_MASK: mask,
        "observation.state_history": torch.randn(batch_size, H, P),
        "observation.subgoal_trace": torch.randn(batch_size, M, P),
        "action": torch.randn(batch_size, N, A),
        "action_is_pad": is_pad,
    }


def leave_adaln_zero(model: SubgoalVLAModel) -> None:
    """adaLN-zero blocks gradients to everything upstream of the DiT output at step 0; perturb the zeros."""
    with torch.no_grad():
        for dit in (model.planner, model.generator):
            if dit is None:
                continue
            for name, p in dit.named_parameters():
                if "adaLN_modulation" in name or "final_layer.linear" in name:
                    p.add_(0.02 * torch.randn_like(p))


def has_grad(module: torch.nn.Module) -> bool:
    return any(p.grad is not None and p.grad.abs().sum() > 0 for p in module.parameters())


def test_stage1_gradients_reach_heads_cross_attentions_and_llm_not_vision() -> None:
    model = SubgoalVLAModel(make_config())
    leave_adaln_zero(model)
    losses = model.compute_losses(make_batch(model), "stage1")
    assert set(losses) == {"planner_loss", "generator_loss", "loss"}
    assert all(torch.isfinite(v) for v in losses.values()) and losses["planner_loss"] > 0
    torch.testing.assert_close(losses["loss"], losses["planner_loss"] + losses["generator_loss"])
    losses["loss"].backward()
    for module in (model.planner, model.generator, model.planner_aggregator, model.generator_aggregator):
        assert has_grad(module)
    assert has_grad(model.backbone.vlm.language_model) and has_grad(model.backbone.vlm.multi_modal_projector)
    assert all(p.grad is None for p in model.backbone.vision_parameters())
    head_ids = {id(p) for p in model.head_parameters()}
    backbone_ids = {id(p) for p in model.backbone.parameters()}
    assert head_ids.isdisjoint(backbone_ids) and len(head_ids) + len(backbone_ids) == len(
        list(model.parameters())
    )


def test_stage1_generator_is_conditioned_on_the_ground_truth_trace() -> None:
    model = SubgoalVLAModel(make_config()).eval()
    leave_adaln_zero(model)
    batch = make_batch(model)
    first = model.compute_losses(batch, "stage1", generator=torch.Generator().manual_seed(0))
    batch["observation.subgoal_trace"] = torch.randn_like(batch["observation.subgoal_trace"])
    second = model.compute_losses(batch, "stage1", generator=torch.Generator().manual_seed(0))
    assert not torch.allclose(first["generator_loss"], second["generator_loss"])


def test_stage2_uses_sampled_traces_and_freezes_the_backbone() -> None:
    model = SubgoalVLAModel(make_config()).eval()
    leave_adaln_zero(model)
    batch = make_batch(model)
    first = model.compute_losses(batch, "stage2", generator=torch.Generator().manual_seed(0))
    batch["observation.subgoal_trace"] = torch.randn_like(batch["observation.subgoal_trace"])
    second = model.compute_losses(batch, "stage2", generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(
        first["generator_loss"], second["generator_loss"]
    )  # GT trace unused by generator
    assert not torch.allclose(
        first["planner_loss"], second["planner_loss"]
    )  # the planner still learns from it
    second["loss"].backward()
    assert all(p.grad is None for p in model.backbone.parameters())
    assert has_grad(model.planner) and has_grad(model.generator) and has_grad(model.generator_aggregator)


def test_sample_actions_shapes_and_seeded_determinism() -> None:
    model = SubgoalVLAModel(make_config()).eval()
    leave_adaln_zero(model)
    batch = make_batch(model)
    actions, trace = model.sample_actions(batch, generator=torch.Generator().manual_seed(5))
    again, _ = model.sample_actions(batch, generator=torch.Generator().manual_seed(5))
    assert actions.shape == (2, N, A) and trace.shape == (2, M, P)
    assert torch.isfinite(actions).all()
    torch.testing.assert_close(actions, again)


def test_backbone_runs_once_per_chunk(monkeypatch: pytest.MonkeyPatch) -> None:
    model = SubgoalVLAModel(make_config()).eval()
    calls = []
    original = model.backbone.forward
    monkeypatch.setattr(model.backbone, "forward", lambda *a, **k: calls.append(1) or original(*a, **k))
    model.sample_actions(make_batch(model))
    model.compute_losses(make_batch(model), "stage2")
    assert len(calls) == 2


@pytest.mark.parametrize(
    ("overrides", "expect_planner"),
    [
        ({"feature_aggregation": "mean"}, True),
        ({"feature_aggregation": "max"}, True),
        ({"feature_aggregation": "attn", "aggregation_top_k": 8}, True),
        ({"use_planner": False}, False),
        ({"subgoal_trace_len": 1}, True),
    ],
)
def test_ablations_compute_finite_losses_and_backprop(overrides: dict, expect_planner: bool) -> None:
    model = SubgoalVLAModel(make_config(**overrides))
    leave_adaln_zero(model)
    batch = make_batch(model)
    losses = model.compute_losses(batch, "stage1")
    assert torch.isfinite(losses["loss"])
    losses["loss"].backward()
    assert has_grad(model.generator) and has_grad(model.generator_aggregator)
    assert has_grad(model.backbone.vlm.language_model)
    assert (model.planner is not None) == expect_planner
    if not expect_planner:
        assert losses["planner_loss"] == 0
    actions, trace = model.eval().sample_actions(batch)
    assert actions.shape == (2, N, A)
    assert (trace is None) if not expect_planner else trace.shape == (2, model.config.subgoal_trace_len, P)


def test_sampler_clip_range_follows_the_target_normalisation() -> None:
    model = SubgoalVLAModel(make_config())  # actions MIN_MAX -> [-1, 1]; trace = states, MEAN_STD z-scores
    assert model.generator_objective.sampler.config.clip_sample_range == 1.0
    assert model.planner_objective.sampler.config.clip_sample_range == 4.0
    config = make_config()
    config.generator.clip_sample_range = 2.5
    assert SubgoalVLAModel(config).generator_objective.sampler.config.clip_sample_range == 2.5
    actions, _ = model.eval().sample_actions(make_batch(model))
    assert actions.abs().max() <= 1.0 + 1e-6


@pytest.mark.slow
def test_tiny_model_overfits_one_batch() -> None:
    """Training reduces both losses and pulls the DDIM samples towards the demonstrated actions and trace."""
    model = SubgoalVLAModel(make_config())
    batch = make_batch(model)
    batch["action"] = batch["action"].clamp(-1, 1)  # MIN_MAX-normalised actions live in [-1, 1]
    batch["observation.subgoal_trace"] = batch["observation.subgoal_trace"].clamp(-3, 3)
    optimizer = torch.optim.AdamW(model.parameters(), lr=2e-3)

    def sample_errors() -> tuple[float, float]:
        actions, trace = model.eval().sample_actions(batch, generator=torch.Generator().manual_seed(0))
        model.train()
        trace_error = (trace - batch["observation.subgoal_trace"]).pow(2).mean().item()
        return (actions - batch["action"])[~batch["action_is_pad"]].pow(2).mean().item(), trace_error

    before, first = sample_errors(), model.compute_losses(batch, "stage1")
    for _ in range(400):
        losses = model.compute_losses(batch, "stage1")
        optimizer.zero_grad()
        losses["loss"].backward()
        optimizer.step()
    after = sample_errors()
    assert losses["generator_loss"] < 0.5 * first["generator_loss"]
    assert losses["planner_loss"] < 0.5 * first["planner_loss"]
    assert after[0] < 0.5 * before[0] and after[1] < 0.5 * before[1]
