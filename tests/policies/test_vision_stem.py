"""The tiny tower's convolutional stem: same token grid as CLIP's patch embedding, chosen by a validated flag,
saved and reloaded with the checkpoint."""

from __future__ import annotations

import pytest
import torch
from helpers.vocabulary import calvin_backbone
from torch import nn

from lerobot_subgoalvla.config_error import ConfigError
from lerobot_subgoalvla.policies.subgoalvla.config_components import BackboneConfig
from lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla import SubgoalVLAPolicy
from lerobot_subgoalvla.policies.subgoalvla.vision_stem import ConvStem, stem_halvings


@pytest.mark.parametrize(
    ("image_size", "patch_size", "halvings"), [(160, 20, 2), (80, 10, 1), (32, 8, 3), (64, 16, 3)]
)
def test_the_stem_gives_the_patch_embeddings_grid(image_size: int, patch_size: int, halvings: int) -> None:
    pixels = torch.randn(2, 3, image_size, image_size)
    patches = nn.Conv2d(3, 64, kernel_size=patch_size, stride=patch_size)
    stem = ConvStem(patch_size, 64)
    assert stem_halvings(patch_size) == halvings
    assert stem(pixels).shape == patches(pixels).shape
    assert stem.weight is stem.projection.weight


def test_the_stem_sees_a_single_pixel_where_it_is() -> None:
    """A one-pixel change reaches only the token whose patch holds it (no token mixing before the ViT)."""
    stem = ConvStem(20, 64).eval()
    pixels = torch.zeros(1, 3, 160, 160)
    moved = pixels.clone()
    moved[0, :, 47, 103] = 1.0  # in patch row 2, column 5
    changed = (stem(moved) - stem(pixels)).abs().sum(dim=1)[0] > 0
    assert changed.nonzero().tolist() == [[2, 5]]


def test_an_odd_patch_has_no_stem() -> None:
    with pytest.raises(ValueError, match="even patch size"):
        ConvStem(5, 64)


def test_the_flag_is_validated(make_config) -> None:
    with pytest.raises(ConfigError, match=r"vision_stem='cnn'.*allowed values: patch, conv"):
        make_config(backbone=calvin_backbone(vision_stem="cnn"))
    with pytest.raises(ConfigError, match=r"vision_stem=conv needs an even --policy.backbone.patch_size"):
        make_config(backbone=calvin_backbone(vision_stem="conv", image_size=35, patch_size=7))
    with pytest.raises(ConfigError, match="backbone.vision_stem only applies to the tiny backbone"):
        make_config(backbone=BackboneConfig(name_or_path="some/vlm", vision_stem="conv"), preset="small")


def test_presets_keep_clips_patch_embedding(make_config) -> None:
    assert make_config().backbone.vision_stem == "patch"
    assert make_config(preset="laptop").backbone.vision_stem == "patch"


def test_a_conv_stem_policy_reloads_exactly(make_config, make_policy_and_processors, tmp_path) -> None:
    policy, _, _ = make_policy_and_processors(make_config(backbone=calvin_backbone(vision_stem="conv")))
    tower = policy.model.backbone.vlm.vision_tower
    assert isinstance(tower.vision_model.embeddings.patch_embedding, ConvStem)
    trains_tower = not policy.config.backbone.freeze_vision_tower
    assert any(p.requires_grad for p in tower.parameters()) == trains_tower
    policy.save_pretrained(tmp_path)
    reloaded = SubgoalVLAPolicy.from_pretrained(tmp_path)
    assert reloaded.config.backbone.vision_stem == "conv"
    original = policy.state_dict()
    stem_keys = [k for k in original if ".patch_embedding.convolutions." in k]
    assert stem_keys
    for key, value in reloaded.state_dict().items():
        assert torch.equal(value, original[key]), key
