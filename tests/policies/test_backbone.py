"""VLMBackbone: layer-k hidden states, padding mask, frozen vision tower, offline from_pretrained, input
helpers."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import torch
from helpers.vocabulary import CALVIN_WORDS, calvin_backbone
from transformers import (
    AutoModel,
    CLIPImageProcessor,
    CLIPVisionConfig,
    LlamaConfig,
    LlavaConfig,
    LlavaForConditionalGeneration,
    Qwen2Config,
    SiglipVisionConfig,
)

from lerobot_subgoalvla.calvin_vocab import EVAL_INSTRUCTIONS
from lerobot_subgoalvla.policies.subgoalvla.backbone import (
    VLMBackbone,
    VLMInputSpec,
    build_tiny_llava_config,
    prepare_pixel_values,
    tokenize_instructions,
)
from lerobot_subgoalvla.policies.subgoalvla.configuration_subgoalvla import SubgoalVLAConfig
from lerobot_subgoalvla.policies.subgoalvla.tokenizer import IMAGE_TOKEN, build_tiny_tokenizer, load_tokenizer

INSTRUCTIONS = ["open the drawer", "push the sliding door to the left side"]

#: The tiny preset's backbone dimensions (the one place they are set).
TINY = SubgoalVLAConfig(preset="tiny", backbone=calvin_backbone()).backbone.tiny_dims()


def _inputs(backbone: VLMBackbone, batch: int = 2) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    tokenizer = build_tiny_tokenizer(CALVIN_WORDS)
    ids, mask = tokenize_instructions(tokenizer, INSTRUCTIONS[:batch], 10, backbone.input_spec)
    pixels = backbone.prepare_pixel_values([torch.rand(batch, 3, 200, 200), torch.rand(batch, 3, 84, 84)])
    return ids, mask, pixels


def test_tiny_tokenizer_is_deterministic_and_covers_calvin_instructions() -> None:
    first, second = build_tiny_tokenizer(CALVIN_WORDS), build_tiny_tokenizer(CALVIN_WORDS)
    assert first.get_vocab() == second.get_vocab()
    for instruction in EVAL_INSTRUCTIONS.values():
        ids = first(instruction, add_special_tokens=False)["input_ids"]
        assert first.unk_token_id not in ids, instruction
    assert first.convert_tokens_to_ids(IMAGE_TOKEN) == build_tiny_llava_config(TINY).image_token_id


def test_tokenize_instructions_expands_image_placeholders_and_pads() -> None:
    spec = VLMInputSpec.load(None, TINY)
    assert spec.num_image_tokens == (32 // 8) ** 2
    ids, mask = tokenize_instructions(build_tiny_tokenizer(CALVIN_WORDS), INSTRUCTIONS, 12, spec)
    assert ids.shape == mask.shape == (2, spec.num_image_tokens + 12)
    assert (ids[:, : spec.num_image_tokens] == spec.image_token_id).all()
    assert (ids[:, spec.num_image_tokens :] != spec.image_token_id).all()
    assert mask[0].sum() == spec.num_image_tokens + 3  # "open the drawer"
    assert mask[1].sum() == spec.num_image_tokens + 8


def test_prepare_pixel_values_places_cameras_side_by_side() -> None:
    static = torch.zeros(1, 3, 200, 200)
    gripper = torch.ones(1, 3, 84, 84)
    pixels = prepare_pixel_values([static, gripper], 32, (0.5, 0.5, 0.5), (0.5, 0.5, 0.5))
    assert pixels.shape == (1, 3, 32, 32)
    torch.testing.assert_close(pixels[..., :16], torch.full((1, 3, 32, 16), -1.0))
    torch.testing.assert_close(pixels[..., 16:], torch.full((1, 3, 32, 16), 1.0))


@pytest.mark.parametrize("num_cameras", [1, 3])
def test_prepare_pixel_values_gives_each_camera_a_strip_in_order(num_cameras: int) -> None:
    """One camera fills the square; K cameras get K strips of R / K columns, left to right in their order."""
    views = [torch.full((1, 3, 48, 64), float(k) / num_cameras) for k in range(num_cameras)]
    pixels = prepare_pixel_values(views, 33, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    assert pixels.shape == (1, 3, 33, 33)
    bounds = [33 * k // num_cameras for k in range(num_cameras + 1)]
    for k, (left, right) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        expected = torch.full((1, 3, 33, right - left), k / num_cameras)
        torch.testing.assert_close(pixels[..., left:right], expected)


def test_prepare_pixel_values_separate_gives_each_camera_its_own_square_sample_by_sample() -> None:
    """``separate``: V full squares per sample, in the order LLaVA fills the sample's V placeholder runs."""
    static = torch.rand(2, 3, 200, 200)
    gripper = torch.rand(2, 3, 84, 84)
    pixels = prepare_pixel_values([static, gripper], 32, (0.0,) * 3, (1.0,) * 3, camera_layout="separate")
    assert pixels.shape == (4, 3, 32, 32)  # (B * V, 3, I, I)
    alone = [prepare_pixel_values([view], 32, (0.0,) * 3, (1.0,) * 3) for view in (static, gripper)]
    for b in range(2):  # sample b's static camera, then its gripper camera: each as if it were the only one
        torch.testing.assert_close(pixels[2 * b], alone[0][b])
        torch.testing.assert_close(pixels[2 * b + 1], alone[1][b])


def test_tokenize_instructions_writes_one_placeholder_run_per_image() -> None:
    spec = VLMInputSpec.load(None, TINY)
    ids, _ = tokenize_instructions(build_tiny_tokenizer(CALVIN_WORDS), INSTRUCTIONS, 12, spec, 2)
    assert ids.shape == (2, 2 * spec.num_image_tokens + 12)
    assert (ids[:, : 2 * spec.num_image_tokens] == spec.image_token_id).all()
    assert (ids[:, 2 * spec.num_image_tokens :] != spec.image_token_id).all()


def test_separate_cameras_each_reach_their_own_image_tokens() -> None:
    """Changing the gripper camera changes the second run of image tokens, not the first (causal LLM)."""
    backbone = VLMBackbone(None, tiny=TINY, camera_layout="separate").eval()
    ids, mask = tokenize_instructions(
        build_tiny_tokenizer(CALVIN_WORDS), INSTRUCTIONS, 10, backbone.input_spec, 2
    )
    static, gripper = torch.rand(2, 3, 200, 200), torch.rand(2, 3, 84, 84)
    with torch.no_grad():
        before, _ = backbone(ids, mask, backbone.prepare_pixel_values([static, gripper]))
        after, _ = backbone(ids, mask, backbone.prepare_pixel_values([static, torch.rand(2, 3, 84, 84)]))
    n = backbone.input_spec.num_image_tokens
    torch.testing.assert_close(after[:, :n], before[:, :n])  # the static camera's tokens
    assert not torch.allclose(after[:, n : 2 * n], before[:, n : 2 * n])


def test_backbone_returns_layer_k_hidden_states_and_mask() -> None:
    backbone = VLMBackbone(None, layer=None, tiny=dataclasses.replace(TINY, text_num_layers=4)).eval()
    assert backbone.layer == 2 and len(backbone.vlm.language_model.layers) == 2  # k = m // 2, truncated
    ids, mask, pixels = _inputs(backbone)
    hidden, valid = backbone(ids, mask, pixels)
    assert hidden.shape == (2, ids.shape[1], 32)
    assert valid.dtype == torch.bool and torch.equal(valid, mask.bool())
    # The same weights in the full 4-layer model: our output must be its hidden_states[k] (pre-final-norm).
    full = AutoModel.from_config(build_tiny_llava_config(dataclasses.replace(TINY, text_num_layers=4))).eval()
    missing, unexpected = full.load_state_dict(backbone.vlm.state_dict(), strict=False)
    assert not unexpected and all(
        ".layers.2." in k or ".layers.3." in k or k.endswith("norm.weight") for k in missing
    )
    with torch.no_grad():
        reference = full(input_ids=ids, attention_mask=mask, pixel_values=pixels, output_hidden_states=True)
    torch.testing.assert_close(hidden, reference.hidden_states[2])
    assert not torch.allclose(hidden, reference.hidden_states[1])


def test_vision_tower_is_frozen_and_stays_in_eval_mode() -> None:
    backbone = VLMBackbone(None, freeze_vision_tower=True, tiny=TINY)
    backbone.train()
    assert not backbone.vlm.vision_tower.training
    assert backbone.vlm.language_model.training
    assert all(not p.requires_grad for p in backbone.vision_parameters())
    ids, mask, pixels = _inputs(backbone)
    hidden, valid = backbone(ids, mask, pixels)
    hidden[valid].pow(2).mean().backward()
    assert all(p.grad is None for p in backbone.vision_parameters())
    assert all(p.grad is not None for p in backbone.projector_parameters())
    assert backbone.vlm.language_model.layers[0].mlp.up_proj.weight.grad.abs().sum() > 0
    groups = [
        backbone.vision_parameters(),
        backbone.projector_parameters(),
        backbone.language_model_parameters(),
    ]
    assert sum(len(g) for g in groups) == len(list(backbone.parameters()))


def test_padding_does_not_change_valid_hidden_states() -> None:
    backbone = VLMBackbone(None, tiny=TINY).eval()
    ids, mask, pixels = _inputs(backbone, batch=1)
    padded_ids = torch.cat([ids, torch.full((1, 5), 0)], dim=1)
    padded_mask = torch.cat([mask, torch.zeros(1, 5, dtype=mask.dtype)], dim=1)
    with torch.no_grad():
        hidden, _ = backbone(ids, mask, pixels)
        padded, valid = backbone(padded_ids, padded_mask, pixels)
    n = int(mask.sum())
    torch.testing.assert_close(padded[:, :n], hidden[:, :n])
    assert valid[:, n:].sum() == 0


def test_bad_layer_is_rejected() -> None:
    with pytest.raises(ValueError, match="layer k=9"):
        VLMBackbone(None, layer=9, tiny=dataclasses.replace(TINY, text_num_layers=4))


def _save_tiny_checkpoint(path: Path) -> LlavaForConditionalGeneration:
    """A tiny LLaVA saved the way llava-hf checkpoints are: model + tokenizer + image processor."""
    config = build_tiny_llava_config(dataclasses.replace(TINY, text_num_layers=4))
    model = LlavaForConditionalGeneration(config).eval()
    model.save_pretrained(path)
    build_tiny_tokenizer(CALVIN_WORDS).save_pretrained(path)
    CLIPImageProcessor(
        size={"shortest_edge": 32},
        crop_size={"height": 32, "width": 32},
        image_mean=[0.5] * 3,
        image_std=[0.5] * 3,
    ).save_pretrained(path)
    return model


def test_from_pretrained_path_loads_offline(tmp_path: Path) -> None:
    saved = _save_tiny_checkpoint(tmp_path)
    backbone = VLMBackbone(str(tmp_path), layer=3).eval()
    assert backbone.layer == 3 and backbone.num_llm_layers == 4
    spec = VLMInputSpec.load(str(tmp_path))
    assert spec == backbone.input_spec and spec.image_mean == (0.5, 0.5, 0.5)
    tokenizer = load_tokenizer(str(tmp_path))
    assert tokenizer.get_vocab() == build_tiny_tokenizer(CALVIN_WORDS).get_vocab()
    ids, mask = tokenize_instructions(tokenizer, INSTRUCTIONS, 10, spec)
    pixels = backbone.prepare_pixel_values([torch.rand(2, 3, 200, 200), torch.rand(2, 3, 84, 84)])
    with torch.no_grad():
        hidden, _ = backbone(ids, mask, pixels)
        reference = saved.model(
            input_ids=ids, attention_mask=mask, pixel_values=pixels, output_hidden_states=True
        )
    torch.testing.assert_close(hidden, reference.hidden_states[3])


def _interleave_like_config(**dims: int) -> LlavaConfig:
    """llava-interleave-qwen-0.5b's layout (SigLIP, no CLS, "full" features from the last layer, Qwen2
    LLM)."""
    vision = SiglipVisionConfig(
        hidden_size=dims.get("vision_hidden", 1152),
        intermediate_size=dims.get("vision_mlp", 4304),
        num_hidden_layers=dims.get("vision_layers", 26),
        num_attention_heads=dims.get("vision_heads", 16),
        image_size=dims.get("image_size", 384),
        patch_size=14,
        vision_use_head=False,
    )
    text = Qwen2Config(
        vocab_size=dims.get("vocab", 152000),
        hidden_size=dims.get("text_hidden", 1024),
        intermediate_size=dims.get("text_mlp", 2816),
        num_hidden_layers=dims.get("text_layers", 24),
        num_attention_heads=dims.get("text_heads", 16),
        num_key_value_heads=dims.get("text_heads", 16),
    )
    return LlavaConfig(
        vision_config=vision,
        text_config=text,
        image_token_index=dims.get("image_token", 151646),
        vision_feature_select_strategy="full",
        vision_feature_layer=-1,
    )


def test_input_spec_counts_image_tokens_of_the_real_presets() -> None:
    small = VLMInputSpec.from_config(_interleave_like_config(), (0.5,) * 3, (0.5,) * 3)
    assert (small.num_image_tokens, small.image_size, small.image_token_id) == (729, 384, 151646)  # 27 x 27
    paper = LlavaConfig(  # llava-1.5: CLIP-L/14-336, CLS dropped by the "default" strategy
        vision_config=CLIPVisionConfig(image_size=336, patch_size=14),
        text_config=LlamaConfig(),
        image_token_index=32000,
    )
    assert VLMInputSpec.from_config(paper, (0.5,) * 3, (0.5,) * 3).num_image_tokens == 576


def test_siglip_qwen_architecture_runs_at_tiny_dims() -> None:
    """The small preset's architecture (SigLIP + Qwen2, "full" features), shrunk: H[k] and mask come out
    right."""
    config = _interleave_like_config(
        vision_hidden=32,
        vision_mlp=64,
        vision_layers=2,
        vision_heads=2,
        image_size=28,
        vocab=64,
        text_hidden=32,
        text_mlp=64,
        text_layers=4,
        text_heads=4,
        image_token=63,
    )
    backbone = VLMBackbone(None, vlm_config=config).eval()
    spec = backbone.input_spec
    assert spec.num_image_tokens == 4 and backbone.layer == 2
    ids = torch.cat([torch.full((2, 4), 63), torch.randint(0, 60, (2, 6))], dim=1)
    mask = torch.ones_like(ids)
    mask[1, -2:] = 0
    pixels = backbone.prepare_pixel_values([torch.rand(2, 3, 200, 200), torch.rand(2, 3, 84, 84)])
    with torch.no_grad():
        hidden, valid = backbone(ids, mask, pixels)
    assert hidden.shape == (2, 10, 32) and valid.sum().item() == 18 and torch.isfinite(hidden).all()
