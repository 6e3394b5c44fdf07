"""``--policy.backbone.camera_layout``: the paper's side-by-side cameras against one image per camera."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from helpers.policy_batches import inference_observation
from helpers.vocabulary import calvin_backbone
from lerobot.utils.constants import OBS_LANGUAGE_TOKENS

from lerobot_subgoalvla.config_error import ConfigError
from lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla import SubgoalVLAPolicy


def test_an_unknown_layout_is_refused_with_the_allowed_values(make_config) -> None:
    with pytest.raises(ConfigError, match=r"--policy.backbone.camera_layout='grid'.*side_by_side, separate"):
        make_config(backbone=calvin_backbone(camera_layout="grid"))


def test_separate_layout_trains_and_reloads_with_one_placeholder_run_per_camera(
    make_config, make_policy_and_processors, raw_batch, tmp_path: Path
) -> None:
    side_by_side = make_config()
    separate = make_config(backbone=calvin_backbone(camera_layout="separate"))
    assert (side_by_side.images_per_sample, separate.images_per_sample) == (1, 2)  # CALVIN's two cameras
    _, pre_side, _ = make_policy_and_processors(side_by_side)
    policy, pre, _ = make_policy_and_processors(separate)
    tokens = pre(dict(raw_batch))[OBS_LANGUAGE_TOKENS]
    image_tokens = (
        pre_side(dict(raw_batch))[OBS_LANGUAGE_TOKENS].shape[1] - side_by_side.backbone.max_instruction_tokens
    )
    assert tokens.shape[1] == 2 * image_tokens + separate.backbone.max_instruction_tokens

    optimizer = separate.get_optimizer_preset().build(policy.get_optim_params())
    policy.train()
    loss, _ = policy.forward(pre(dict(raw_batch)))
    loss.backward()
    optimizer.step()
    assert torch.isfinite(loss)
    policy.eval()
    policy.save_pretrained(tmp_path)
    reloaded = SubgoalVLAPolicy.from_pretrained(tmp_path)
    assert reloaded.config.backbone.camera_layout == "separate"
    obs = inference_observation(pre(dict(raw_batch)))
    torch.manual_seed(0)
    expected = policy.predict_action_chunk(obs)
    torch.manual_seed(0)
    assert torch.equal(reloaded.predict_action_chunk(obs), expected)
