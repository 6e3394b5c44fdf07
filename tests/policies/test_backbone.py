"""VLMBackbone: layer-k hidden states, padding mask, frozen vision tower, offline from_pretrained, input helpers."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from transformers import AutoModel, CLIPImageProcessor, LlavaForConditionalGeneration

from lerobot_subgoalvla.calvin_vocab import EVAL_INSTRUCTIONS
from lerobot_subgoalvla.policies.subgoalvla.backbone import (
    IMAGE_TOKEN,
    TinyLlavaDims,
    VLMBackbone,
    VLMInputSpec,
    build_tiny_llava_config,
    build_tiny_tokenizer,
    load_tokenizer,
    prepare_pixel_values,
    tokenize_instructions,
)

INSTRUCTIONS = ["open the drawer", "push the sliding door to the left side"]


def _inputs(backbone: VLMBackbone, batch: int = 2) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    tokenizer = build_tiny_tokenizer()
    ids, mask = tokenize_instructions(tokenizer, INSTRUCTIONS[:batch], 10, backbone.input_spec)
    pixels = backbone.prepare_pixel_values(torch.rand(batch, 3, 200, 200), torch.rand(batch, 3, 84, 84))
    return ids, mask, pixels


def test_tiny_tokenizer_is_deterministic_and_covers_calvin_instructions() -> None:
    first, second = build_tiny_tokenizer(), build_tiny_tokenizer()
    assert first.get_vocab() == second.get_vocab()
    for instruction in EVAL_INSTRUCTIONS.values():
        ids = first(instruction, add_special_tokens=False)["input_ids"]
        assert first.unk_token_id not in ids, instruction
    assert first.convert_tokens_to_ids(IMAGE_TOKEN) == build_tiny_llava_config(TinyLlavaDims()).image_token_id


def test_tokenize_instructions_expands_image_placeholders_and_pads() -> None:
    spec = VLMInputSpec.load(None, TinyLlavaDims())
    assert spec.num_image_tokens == (32 // 8) ** 2
    ids, mask = tokenize_instructions(build_tiny_tokenizer(), INSTRUCTIONS, 12, spec)
    assert ids.shape == mask.shape == (2, spec.num_image_tokens + 12)
    assert (ids[:, : spec.num_image_tokens] == spec.image_token_id).all()
    assert (ids[:, spec.num_image_tokens :] != spec.image_token_id).all()
    assert mask[0].sum() == spec.num_image_tokens + 3  # "open the drawer"
    assert mask[1].sum() == spec.num_image_tokens + 8


def test_prepare_pixel_values_places_cameras_side_by_side() -> None:
    static = torch.zeros(1, 3, 200, 200)
    gripper = torch.ones(1, 3, 84, 84)
    pixels = prepare_pixel_values(static, gripper, 32, (0.5, 0.5, 0.5), (0.5, 0.5, 0.5))
    assert pixels.shape == (1, 3, 32, 32)
    torch.testing.assert_close(pixels[..., :16], torch.full((1, 3, 32, 16), -1.0))
    torch.testing.assert_close(pixels[..., 16:], torch.full((1, 3, 32, 16), 1.0))


def test_backbone_returns_layer_k_hidden_states_and_mask() -> None:
    backbone = VLMBackbone(None, layer=None, tiny=TinyLlavaDims(text_num_layers=4)).eval()
    assert backbone.layer == 2 and len(backbone.vlm.language_model.layers) == 2  # k = m // 2, truncated
    ids, mask, pixels = _inputs(backbone)
    hidden, valid = backbone(ids, mask, pixels)
    assert hidden.shape == (2, ids.shape[1], 32)
    assert valid.dtype == torch.bool and torch.equal(valid, mask.bool())
    # The same weights in the full 4-layer model: our output must be its hidden_states[k] (pre-final-norm).
    full = AutoModel.from_config(build_tiny_llava_config(TinyLlavaDims(text_num_layers=4))).eval()
    missing, unexpected = full.load_state_dict(backbone.vlm.state_dict(), strict=False)
    assert not unexpected and all(
        ".layers.2." in k or ".layers.3." in k or k.endswith("norm.weight") for k in missing
    )
    with torch.no_grad():
        reference = full(input_ids=ids, attention_mask=mask, pixel_values=pixels, output_hidden_states=True)
    torch.testing.assert_close(hidden, reference.hidden_states[2])
    assert not torch.allclose(hidden, reference.hidden_states[1])


def test_vision_tower_is_frozen_and_stays_in_eval_mode() -> None:
    backbone = VLMBackbone(None, freeze_vision_tower=True)
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
    backbone = VLMBackbone(None).eval()
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
        VLMBackbone(None, layer=9, tiny=TinyLlavaDims(text_num_layers=4))


def _save_tiny_checkpoint(path: Path) -> LlavaForConditionalGeneration:
    """A tiny LLaVA saved the way llava-hf checkpoints are: model + tokenizer + image processor."""
    config = build_tiny_llava_config(TinyLlavaDims(text_num_layers=4))
    model = LlavaForConditionalGeneration(config).eval()
    model.save_pretrained(path)
    build_tiny_tokenizer().save_pretrained(path)
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
    assert tokenizer.get_vocab() == build_tiny_tokenizer().get_vocab()
    ids, mask = tokenize_instructions(tokenizer, INSTRUCTIONS, 10, spec)
    pixels = backbone.prepare_pixel_values(torch.rand(2, 3, 200, 200), torch.rand(2, 3, 84, 84))
    with torch.no_grad():
        hidden, _ = backbone(ids, mask, pixels)
        reference = saved.model(
            input_ids=ids, attention_mask=mask, pixel_values=pixels, output_hidden_states=True
        )
    torch.testing.assert_close(hidden, reference.hidden_states[3])
