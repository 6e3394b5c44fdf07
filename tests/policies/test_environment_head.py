"""The auxiliary environment-state head: off by default, its loss trains the vision tower in stage I only,
it fits its target, its statistics come from the dataset and survive a reload, and bad settings end in one
line."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from helpers.vocabulary import calvin_backbone

from lerobot_subgoalvla.config_error import ConfigError, DatasetContractError
from lerobot_subgoalvla.contract.keys import ENV_STATE_KEY
from lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla import SubgoalVLAPolicy


def _with_head(make_config, **overrides):
    """A tiny config whose vision tower trains, with the auxiliary head on."""
    return make_config(
        environment_state_weight=1.0, backbone=calvin_backbone(freeze_vision_tower=False), **overrides
    )


def test_the_head_is_off_by_default(make_config, make_policy_and_processors, raw_batch):
    policy, pre, _ = make_policy_and_processors(make_config())
    assert policy.model.environment_head is None
    _, logs = policy.forward(pre(dict(raw_batch)))
    assert "environment_state_loss" not in logs


def test_its_loss_joins_stage_one_and_reaches_the_vision_tower(
    make_config, make_policy_and_processors, raw_batch
):
    policy, pre, _ = make_policy_and_processors(_with_head(make_config))
    batch = pre(dict(raw_batch))
    policy.train()
    loss, logs = policy.forward(batch)
    assert logs["environment_state_loss"] > 0
    total = logs["planner_loss"] + logs["generator_loss"] + logs["environment_state_loss"]
    assert loss.item() == pytest.approx(total, rel=1e-5)
    losses = policy.model.compute_losses(batch, "stage1")
    losses["environment_state_loss"].backward()  # the auxiliary loss alone
    vision = policy.model.backbone.vision_parameters()
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in vision)
    head = {id(p) for p in policy.model.environment_head.parameters()}
    assert head <= {id(p) for group in policy.get_optim_params() for p in group["params"]}
    assert policy.model.compute_losses(batch, "stage2")["environment_state_loss"].item() == 0


def test_the_head_fits_its_target(make_config, make_policy_and_processors, raw_batch):
    policy, pre, _ = make_policy_and_processors(_with_head(make_config))
    batch = pre(dict(raw_batch))
    optimizer = policy.config.get_optimizer_preset().build(policy.get_optim_params())
    policy.train()
    first = None
    for _ in range(30):
        loss = policy.model.compute_losses(batch, "stage1")["environment_state_loss"]
        first = loss.item() if first is None else first
        loss.backward()
        optimizer.step()
        optimizer.zero_grad()
    assert loss.item() < 0.5 * first


def test_the_statistics_come_from_the_dataset_and_survive_a_reload(
    make_config, make_policy_and_processors, tiny_dataset, tmp_path: Path
):
    policy, _, _ = make_policy_and_processors(_with_head(make_config))
    stats = tiny_dataset.meta.stats[ENV_STATE_KEY]
    head = policy.model.environment_head
    assert torch.allclose(head.target_mean, torch.as_tensor(stats["mean"], dtype=torch.float32))
    policy.save_pretrained(tmp_path)
    loaded = SubgoalVLAPolicy.from_pretrained(tmp_path)
    assert torch.equal(loaded.model.environment_head.target_mean, head.target_mean)
    assert torch.equal(loaded.model.environment_head.target_std, head.target_std)


def test_a_negative_weight_is_refused(make_config):
    with pytest.raises(ConfigError, match="environment_state_weight must be >= 0"):
        make_config(environment_state_weight=-1.0)


def test_a_dataset_without_environment_state_names_the_flag(make_config):
    config = _with_head(make_config)
    config.input_features.pop(ENV_STATE_KEY)
    with pytest.raises(DatasetContractError, match="environment_state_weight=0"):
        SubgoalVLAPolicy(config)
