"""The backbone architectures of the presets, built without downloading anything (shared by the benchmarks).

``small`` and ``paper`` name Hub checkpoints; their transformers configs are written out here with the
numbers of the checkpoints' ``config.json`` (checked against the files on the Hub:
``llava-hf/llava-1.5-7b-hf`` and ``llava-hf/llava-interleave-qwen-0.5b-hf``), so the real architectures can be
instantiated on the ``meta`` device (sizes) or with random weights (latency, memory) on a machine without the
Hub. ``build_model`` returns the policy's model for a preset with CALVIN's two cameras, 15-d state and 7-d
action.
"""

from __future__ import annotations

import torch
from lerobot.configs import FeatureType, PolicyFeature
from lerobot.utils.constants import OBS_LANGUAGE_ATTENTION_MASK, OBS_LANGUAGE_TOKENS
from transformers import CLIPVisionConfig, LlamaConfig, LlavaConfig, Qwen2Config, SiglipVisionConfig

from lerobot_subgoalvla.calvin_vocab import ALL_INSTRUCTIONS
from lerobot_subgoalvla.contract.calvin import GRIPPER_CAMERA_KEY, STATIC_CAMERA_KEY
from lerobot_subgoalvla.contract.keys import (
    ACTION_IS_PAD_KEY,
    ACTION_KEY,
    STATE_HISTORY_KEY,
    STATE_KEY,
    SUBGOAL_TRACE_KEY,
)
from lerobot_subgoalvla.policies.subgoalvla.backbone import VLMBackbone
from lerobot_subgoalvla.policies.subgoalvla.config_components import BackboneConfig
from lerobot_subgoalvla.policies.subgoalvla.configuration_subgoalvla import SubgoalVLAConfig
from lerobot_subgoalvla.policies.subgoalvla.model import SubgoalVLAModel
from lerobot_subgoalvla.policies.subgoalvla.tokenizer import vocabulary_words

STATE_DIM, ACTION_DIM = 15, 7


def architecture(
    preset: str, text_layers: int | None = None, vision_layers: int | None = None
) -> LlavaConfig | None:
    """The backbone architecture of a preset; None = the preset's tiny random LLaVA.

    ``text_layers`` / ``vision_layers`` shorten the LLM / vision tower (reduced-depth copies for memory
    measurements); None keeps the checkpoint's depth. Every number below is the checkpoint's ``config.json``;
    a field it leaves out takes transformers' default, which is then the checkpoint's value.
    """
    if preset == "paper":  # llava-hf/llava-1.5-7b-hf: CLIP ViT-L/14-336 + Vicuna-7B v1.5 (LLaMA-2 7B)
        return LlavaConfig(
            vision_config=CLIPVisionConfig(  # vision_config of the checkpoint
                hidden_size=1024,
                intermediate_size=4096,
                num_hidden_layers=vision_layers or 24,
                num_attention_heads=16,
                image_size=336,
                patch_size=14,
                projection_dim=768,
            ),
            # text_config lists only vocab_size 32064; width 4096, MLP 11008, 32 layers and 32 heads are
            # LlamaConfig's defaults (LLaMA-7B), which the checkpoint relies on.
            text_config=LlamaConfig(
                vocab_size=32064,
                hidden_size=4096,
                intermediate_size=11008,
                num_hidden_layers=text_layers or 32,
                num_attention_heads=32,
            ),
            image_token_index=32000,  # vision_feature_layer -2 / strategy "default": LlavaConfig's defaults
        )
    if preset == "small":  # llava-hf/llava-interleave-qwen-0.5b-hf: SigLIP-so400m-384 + Qwen1.5-0.5B
        return LlavaConfig(
            vision_config=SiglipVisionConfig(
                hidden_size=1152,
                intermediate_size=4304,
                num_hidden_layers=vision_layers or 26,
                num_attention_heads=16,
                image_size=384,
                patch_size=14,
                vision_use_head=False,
            ),
            text_config=Qwen2Config(
                vocab_size=152000,  # the config's vocab_size (151646 is the image token's id)
                hidden_size=1024,
                intermediate_size=2816,
                num_hidden_layers=text_layers or 24,
                num_attention_heads=16,
                num_key_value_heads=16,
                tie_word_embeddings=True,
            ),
            image_token_index=151646,
            vision_feature_select_strategy="full",
            vision_feature_layer=-1,
        )
    return None


#: presets with a tiny random backbone, whose vocabulary comes from the training data.
TINY = ("tiny", "laptop")


def make_config(preset: str, **overrides: object) -> SubgoalVLAConfig:
    features = {
        STATE_KEY: PolicyFeature(type=FeatureType.STATE, shape=(STATE_DIM,)),
        STATIC_CAMERA_KEY: PolicyFeature(type=FeatureType.VISUAL, shape=(3, 200, 200)),
        GRIPPER_CAMERA_KEY: PolicyFeature(type=FeatureType.VISUAL, shape=(3, 84, 84)),
    }
    actions = {ACTION_KEY: PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))}
    # a tiny backbone's vocabulary comes from the training data; here CALVIN's, as lerobot-train would fill it
    backbone = BackboneConfig(vocabulary=list(vocabulary_words(ALL_INSTRUCTIONS)) if preset in TINY else None)
    overrides.setdefault("device", "cpu")  # the config's device only; the model is built where asked
    return SubgoalVLAConfig(
        preset=preset, input_features=features, output_features=actions, backbone=backbone, **overrides
    )


def build_model(
    preset: str,
    device: str,
    config: SubgoalVLAConfig | None = None,
    vlm_config: LlavaConfig | None = None,
) -> SubgoalVLAModel:
    """The preset's model on ``device`` (``meta`` for sizes/FLOPs) without downloading weights.

    ``config`` (from ``make_config(preset, ...)``) and ``vlm_config`` (from ``architecture(preset, ...)``)
    replace the preset's own, e.g. for a reduced-depth copy.
    """
    config = make_config(preset) if config is None else config
    vlm_config = architecture(preset) if vlm_config is None else vlm_config
    bb = config.backbone
    with torch.device(device):
        backbone = VLMBackbone(
            None,
            bb.layer,
            bb.freeze_vision_tower,
            tiny=config.backbone.tiny_dims(),
            torch_dtype=bb.torch_dtype if device != "cpu" else "float32",
            vlm_config=vlm_config,
        )
        return SubgoalVLAModel(config, backbone=backbone).eval()


def fake_inputs(model: SubgoalVLAModel, device: str, batch: int = 1) -> dict[str, torch.Tensor]:
    """An inference batch: CALVIN's two cameras, a full-length instruction, the state history."""
    spec = model.backbone.input_spec
    length = spec.num_image_tokens + model.config.backbone.max_instruction_tokens
    ids = torch.zeros(batch, length, dtype=torch.long, device=device)
    ids[:, : spec.num_image_tokens] = spec.image_token_id
    return {
        STATIC_CAMERA_KEY: torch.rand(batch, 3, 200, 200, device=device),
        GRIPPER_CAMERA_KEY: torch.rand(batch, 3, 84, 84, device=device),
        OBS_LANGUAGE_TOKENS: ids,
        OBS_LANGUAGE_ATTENTION_MASK: torch.ones(batch, length, dtype=torch.long, device=device),
        STATE_HISTORY_KEY: torch.randn(batch, model.config.state_history_len, STATE_DIM, device=device),
    }


def training_batch(model: SubgoalVLAModel, device: str, batch: int = 1) -> dict[str, torch.Tensor]:
    """``fake_inputs`` plus the training targets: the subgoal trace and an action chunk."""
    cfg = model.config
    return {
        **fake_inputs(model, device, batch),
        SUBGOAL_TRACE_KEY: torch.randn(batch, cfg.subgoal_trace_len, STATE_DIM, device=device),
        ACTION_KEY: torch.randn(batch, cfg.chunk_size, ACTION_DIM, device=device),
        ACTION_IS_PAD_KEY: torch.zeros(batch, cfg.chunk_size, dtype=torch.bool, device=device),
    }
