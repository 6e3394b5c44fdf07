"""``--policy.gradient_checkpointing``: same loss and gradients, blocks recomputed, saved with the config.

The memory it saves is measured by ``benchmarks/memory_plan.py`` (docs/memory.md), not here.
"""

from __future__ import annotations

import draccus
import pytest
import torch
from helpers.vocabulary import CALVIN_WORDS, calvin_backbone
from lerobot.configs import FeatureType, PolicyFeature, PreTrainedConfig
from lerobot.utils.constants import OBS_LANGUAGE_ATTENTION_MASK, OBS_LANGUAGE_TOKENS
from torch import nn

from lerobot_subgoalvla.policies.subgoalvla.backbone import tokenize_instructions
from lerobot_subgoalvla.policies.subgoalvla.configuration_subgoalvla import SubgoalVLAConfig
from lerobot_subgoalvla.policies.subgoalvla.model import SubgoalVLAModel
from lerobot_subgoalvla.policies.subgoalvla.tokenizer import build_tiny_tokenizer

P, A, H, M, N = 15, 7, 15, 8, 15


def make_config(gradient_checkpointing: bool) -> SubgoalVLAConfig:
    """Tiny preset with dropout in the cross-attention, so the recomputation must redraw the same masks."""
    config = SubgoalVLAConfig(
        preset="tiny",
        backbone=calvin_backbone(),
        input_features={
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(P,)),
            "observation.images.static": PolicyFeature(type=FeatureType.VISUAL, shape=(3, 32, 32)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(A,))},
        gradient_checkpointing=gradient_checkpointing,
    )
    for attention in (config.planner_attention, config.generator_attention):
        attention.dropout = 0.2
    config.planner.repeated_diffusion_steps = 2
    config.generator.repeated_diffusion_steps = 2
    return config


def make_batch(model: SubgoalVLAModel) -> dict[str, torch.Tensor]:
    ids, mask = tokenize_instructions(
        build_tiny_tokenizer(CALVIN_WORDS),
        ["open the drawer", "push the red block to the left"],
        12,
        model.backbone.input_spec,
    )
    generator = torch.Generator().manual_seed(1)
    return {
        "observation.images.static": torch.rand(2, 3, 32, 32, generator=generator),
        OBS_LANGUAGE_TOKENS: ids,
        OBS_LANGUAGE_ATTENTION_MASK: mask,
        "observation.state_history": torch.randn(2, H, P, generator=generator),
        "observation.subgoal_trace": torch.randn(2, M, P, generator=generator),
        "action": torch.randn(2, N, A, generator=generator),
    }


def perturb_adaln_zero(model: SubgoalVLAModel) -> None:
    """adaLN-zero stops every gradient upstream of the DiT output at initialisation; move off the zeros."""
    generator = torch.Generator().manual_seed(2)
    with torch.no_grad():
        for name, p in model.named_parameters():
            if "adaLN_modulation" in name or "final_layer.linear" in name:
                p.add_(0.02 * torch.randn(p.shape, generator=generator))


def loss_and_gradients(model: SubgoalVLAModel, batch: dict[str, torch.Tensor], stage: str) -> tuple:
    model.train()
    model.zero_grad(set_to_none=True)
    torch.manual_seed(3)  # dropout draws from the global RNG
    loss = model.compute_losses(batch, stage, generator=torch.Generator().manual_seed(0))["loss"]
    loss.backward()
    return loss.detach(), {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}


def count_calls(modules: dict[str, nn.Module]) -> dict[str, int]:
    """Count the calls of each module (a recomputed block runs twice).

    Pre-hooks: the recomputation stops as soon as it has rebuilt what the backward pass needs, before the end
    of the block's forward, so a forward (post-)hook would not see it.
    """
    calls = dict.fromkeys(modules, 0)
    for name, module in modules.items():

        def hook(*_: object, name: str = name) -> None:
            calls[name] += 1

        module.register_forward_pre_hook(hook)
    return calls


def checkpointed_blocks(model: SubgoalVLAModel) -> dict[str, nn.Module]:
    return {
        "llm layer": model.backbone.vlm.language_model.layers[0],
        "planner cross-attention": model.planner_aggregator.blocks[0],
        "generator cross-attention": model.generator_aggregator.blocks[0],
        "planner DiT": model.planner.blocks[0],
        "generator DiT": model.generator.blocks[0],
    }


@pytest.mark.parametrize("stage", ["stage1", "stage2"])
def test_checkpointing_gives_the_same_loss_and_gradients(stage: str) -> None:
    plain = SubgoalVLAModel(make_config(gradient_checkpointing=False))
    perturb_adaln_zero(plain)
    checkpointed = SubgoalVLAModel(make_config(gradient_checkpointing=True))
    checkpointed.load_state_dict(plain.state_dict())
    batch = make_batch(plain)
    loss, grads = loss_and_gradients(plain, batch, stage)
    loss_ckpt, grads_ckpt = loss_and_gradients(checkpointed, batch, stage)
    torch.testing.assert_close(loss_ckpt, loss, rtol=1e-6, atol=1e-7)
    assert grads_ckpt.keys() == grads.keys() and any("language_model.layers" in n for n in grads) == (
        stage == "stage1"
    )
    for name, grad in grads.items():
        torch.testing.assert_close(grads_ckpt[name], grad, rtol=1e-4, atol=1e-6, msg=name)


def test_checkpointed_blocks_run_again_in_the_backward_pass_and_only_in_training() -> None:
    model = SubgoalVLAModel(make_config(gradient_checkpointing=True))
    calls = count_calls(checkpointed_blocks(model))
    batch = make_batch(model)
    model.train()
    loss = model.compute_losses(batch, "stage1")["loss"]
    forward_calls = dict(calls)
    loss.backward()
    assert all(calls[name] == 2 * forward_calls[name] > 0 for name in calls), (forward_calls, calls)
    model.eval()  # inference: no checkpoint, a single pass
    before = dict(calls)
    with torch.no_grad():
        model.compute_losses(batch, "stage1")
    assert all(calls[name] - before[name] == forward_calls[name] for name in calls)


def test_without_the_flag_no_block_is_recomputed() -> None:
    model = SubgoalVLAModel(make_config(gradient_checkpointing=False))
    calls = count_calls(checkpointed_blocks(model))
    model.train()
    loss = model.compute_losses(make_batch(model), "stage1")["loss"]
    forward_calls = dict(calls)
    loss.backward()
    assert calls == forward_calls


def test_the_flag_is_parsed_saved_and_reloaded(tmp_path) -> None:
    assert SubgoalVLAConfig().gradient_checkpointing is False
    cfg = draccus.parse(SubgoalVLAConfig, args=["--device=cpu", "--gradient_checkpointing=true"])
    assert cfg.gradient_checkpointing is True
    cfg.save_pretrained(tmp_path)
    loaded = PreTrainedConfig.from_pretrained(tmp_path)
    assert isinstance(loaded, SubgoalVLAConfig) and loaded.gradient_checkpointing is True
