"""Vision-language backbone: any LLaVA-style transformers VLM -> hidden states H[k] of LLM layer k (paper
4.1).

SubgoalVLA reads the contextualised states of an *intermediate* LLM layer (k = m / 2, following GR00T-N1) as
keys and values of the proprioceptive cross-attention. We load the VLM through transformers' Auto classes (no
vendored modeling code) and keep its base model (vision tower + multi-modal projector + language model,
without the LM head). The decoder is TRUNCATED to its first k layers and its final norm replaced by the
identity, so the LLM's ``last_hidden_state`` IS H[k] (the output of decoder layer k, exactly
``hidden_states[k]`` of the full model) and layers k+1..m cost neither compute nor memory. The dropped layers
are not in the state dict, and a reloaded policy truncates the same way, so checkpoints stay consistent.

Supported: checkpoints of the LLaVA architecture (``model_type="llava"``, one square image) with any vision
tower and LLM transformers provides, e.g. LLaVA-1.5 (CLIP + LLaMA, the ``paper`` preset) and LLaVA-Interleave
(SigLIP + Qwen, the ``small`` preset). Other VLMs whose base model has ``vision_tower``,
``multi_modal_projector`` and ``language_model.layers/norm`` load, but their own prompt/pixel conventions
(PaliGemma's prefix, LLaVA-NeXT's tiling) are not reproduced by the input helpers. ``name_or_path=None``
builds a randomly initialised tiny LLaVA from a config plus an offline word-level tokenizer
(``build_tiny_tokenizer``) for tests and CPU runs.

Input helpers the processor and model call:
``tokenizer.py`` - the tokenizers; ``VLMInputSpec.load`` - image size, mean/std
and image-placeholder facts from the model config alone (no weights); ``tokenize_instructions`` - LLaVA-style
input ids with the ``<image>`` placeholder expanded to one id per image token; ``prepare_pixel_values`` - the
cameras side by side, resized to the vision tower's size and normalised with its statistics.

Dimension legend (the package's, ``__init__.py``): ``B`` batch, ``S`` VLM tokens (image placeholders +
instruction), ``E`` LLM hidden size, ``V`` cameras, ``H, W`` camera image size, ``I`` vision-tower image
side.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F  # noqa: N812
from einops import rearrange
from torch import Tensor, nn
from transformers import (
    AutoConfig,
    AutoImageProcessor,
    AutoModel,
    AutoModelForImageTextToText,
    CLIPVisionConfig,
    LlamaConfig,
    LlavaConfig,
    PretrainedConfig,
    PreTrainedTokenizerBase,
)
from transformers.utils.constants import OPENAI_CLIP_MEAN, OPENAI_CLIP_STD

from lerobot_subgoalvla.policies.subgoalvla.config_components import TinyLlavaDims
from lerobot_subgoalvla.policies.subgoalvla.tokenizer import IMAGE_TOKEN, PAD_TOKEN, tiny_vocabulary
from lerobot_subgoalvla.policies.subgoalvla.vision_stem import install_conv_stem

_DTYPES = {"float32": torch.float32, "bfloat16": torch.bfloat16, "float16": torch.float16}


# ------------------------------------------------------------------------------------------------------------
# Model config and input facts
# ------------------------------------------------------------------------------------------------------------
def build_tiny_llava_config(dims: TinyLlavaDims) -> LlavaConfig:
    """A LLaVA-1.5-architecture config (CLIP vision tower, 2-layer GELU projector, LLaMA) at tiny
    dimensions."""
    vocab = tiny_vocabulary(dims.vocabulary)
    vision = CLIPVisionConfig(
        hidden_size=dims.vision_hidden_size,
        intermediate_size=4 * dims.vision_hidden_size,
        num_hidden_layers=dims.vision_num_layers,
        num_attention_heads=dims.vision_num_heads,
        image_size=dims.image_size,
        patch_size=dims.patch_size,
    )
    text = LlamaConfig(
        vocab_size=len(vocab),
        hidden_size=dims.text_hidden_size,
        intermediate_size=dims.text_intermediate_size,
        num_hidden_layers=dims.text_num_layers,
        num_attention_heads=dims.text_num_heads,
        num_key_value_heads=dims.text_num_heads,
        max_position_embeddings=1024,
        pad_token_id=vocab.index(PAD_TOKEN),
        bos_token_id=None,
        eos_token_id=None,
    )
    num_image_tokens = (dims.image_size // dims.patch_size) ** 2  # "default" strategy drops CLIP's CLS token
    return LlavaConfig(
        vision_config=vision,
        text_config=text,
        image_token_index=vocab.index(IMAGE_TOKEN),
        image_seq_length=num_image_tokens,
    )


def _required_tiny(tiny: TinyLlavaDims | None) -> TinyLlavaDims:
    if tiny is None:
        raise ValueError(
            "a tiny backbone (name_or_path=None) needs its TinyLlavaDims (BackboneConfig.tiny_dims())"
        )
    return tiny


def load_vlm_config(name_or_path: str | None, tiny: TinyLlavaDims | None = None) -> PretrainedConfig:
    """The VLM's config without its weights (``AutoConfig`` for checkpoints, ``build_tiny_llava_config``
    else)."""
    if name_or_path is None:
        return build_tiny_llava_config(_required_tiny(tiny))
    return AutoConfig.from_pretrained(name_or_path)


@dataclass(frozen=True)
class VLMInputSpec:
    """What the inputs of a given VLM must look like.

    Attributes:
        image_token_id: id of the image placeholder token in ``input_ids``.
        num_image_tokens: placeholders per image = visual tokens the vision tower + projector produce.
        image_size: I, the vision tower's square input size (336 for CLIP ViT-L/14-336, 384 for SigLIP).
        image_mean, image_std: per-channel normalisation of the vision tower.
    """

    image_token_id: int
    num_image_tokens: int
    image_size: int
    image_mean: tuple[float, float, float]
    image_std: tuple[float, float, float]

    @classmethod
    def from_config(
        cls, config: PretrainedConfig, image_mean: tuple[float, ...], image_std: tuple[float, ...]
    ) -> VLMInputSpec:
        """Derive the facts from a LLaVA-style config (as LlavaProcessor counts image tokens)."""
        vision = config.vision_config
        num = (vision.image_size // vision.patch_size) ** 2
        has_cls = vision.model_type == "clip_vision_model"  # CLIP prepends a CLS token, SigLIP does not
        strategy = getattr(
            config, "vision_feature_select_strategy", "full"
        )  # no such option: keep all tokens
        num += int(has_cls) - int(strategy == "default")
        return cls(config.image_token_id, num, vision.image_size, tuple(image_mean), tuple(image_std))

    @classmethod
    def load(cls, name_or_path: str | None, tiny: TinyLlavaDims | None = None) -> VLMInputSpec:
        """Spec of a checkpoint (config + image processor, no weights) or of the tiny model (CLIP
        statistics)."""
        config = load_vlm_config(name_or_path, tiny)
        if name_or_path is None:
            return cls.from_config(config, OPENAI_CLIP_MEAN, OPENAI_CLIP_STD)
        image_processor = AutoImageProcessor.from_pretrained(name_or_path)
        return cls.from_config(config, image_processor.image_mean, image_processor.image_std)


def tokenize_instructions(
    tokenizer: PreTrainedTokenizerBase,
    instructions: list[str],
    max_length: int,
    spec: VLMInputSpec,
    images_per_sample: int = 1,
) -> tuple[Tensor, Tensor]:
    """LLaVA-protocol input ids: ``[BOS] <image> x (images_per_sample * num_image_tokens), instruction
    tokens, padding``.

    The image placeholder is written as ``num_image_tokens`` copies of its id per image (LLaVA replaces
    each by one visual token, image after image). Instructions are truncated/right-padded to ``max_length``
    tokens so every batch has the same length ``S = [1 +] images_per_sample * num_image_tokens +
    max_length``; causal attention means valid tokens never see the right padding.

    Args:
        tokenizer: from ``load_tokenizer``.
        instructions: B instruction strings.
        max_length: instruction tokens kept (BackboneConfig.max_instruction_tokens).
        spec: the VLM's input facts.
        images_per_sample: images the vision tower encodes per sample (``camera_layout=separate``: V).

    Returns:
        input_ids (B, S) int64 and attention_mask (B, S) int64 (1 = valid).
    """
    text = tokenizer(
        [instruction.strip() for instruction in instructions],
        add_special_tokens=False,
        padding="max_length",
        truncation=True,
        max_length=max_length,
        return_tensors="pt",
    )
    b = len(instructions)
    prefix = [spec.image_token_id] * (spec.num_image_tokens * images_per_sample)
    if tokenizer.bos_token_id is not None:
        prefix = [tokenizer.bos_token_id, *prefix]
    prefix_ids = torch.tensor(prefix, dtype=torch.long).expand(b, -1)
    input_ids = torch.cat([prefix_ids, text["input_ids"].long()], dim=1)  # (B, S)
    attention_mask = torch.cat([torch.ones_like(prefix_ids), text["attention_mask"].long()], dim=1)  # (B, S)
    return input_ids, attention_mask


def _resized(view: Tensor, height: int, width: int) -> Tensor:
    return F.interpolate(
        view.float(), size=(height, width), mode="bilinear", align_corners=False, antialias=True
    )


def prepare_pixel_values(
    views: Sequence[Tensor],
    image_size: int,
    image_mean: tuple[float, ...],
    image_std: tuple[float, ...],
    camera_layout: str = "side_by_side",
) -> Tensor:
    """The cameras as the vision tower's square images, normalised (paper appendix A).

    ``side_by_side``, the paper's layout: the paper concatenates CALVIN's two views and resizes the result to
    the tower's square input; with V cameras view k is resized to the k-th vertical strip of an R x R image
    (R x R/V, left to right in the given order), which equals concatenating and then resizing. One camera
    fills the square. Appendix A says 334 x 334, but CLIP ViT-L/14-336 (LLaVA-1.5) takes 336 (334 is not a
    multiple of 14), so R is the vision tower's own ``image_size`` (336 paper, 384 SigLIP in ``small``).
    ``separate``: each view resized to its own R x R image, the V images of a sample one after the other
    (LLaVA fills the sample's V runs of image placeholders in that order): a small tower then sees each
    camera at its full size instead of squeezed to 1/V of the width.

    Args:
        views: V >= 1 camera images (B, 3, H_k, W_k) in [0, 1], in the policy's camera order.
        image_size: R.
        image_mean, image_std: 3 channel statistics of the vision tower.
        camera_layout: ``side_by_side`` or ``separate``.

    Returns:
        (B, 3, I, I) normalised pixel values, or (B * V, 3, I, I) with ``separate``.
    """
    if not views:
        raise ValueError("prepare_pixel_values needs at least one camera image")
    if camera_layout == "separate":
        images = torch.stack([_resized(view, image_size, image_size) for view in views])  # (V, B, 3, I, I)
        pixels = rearrange(images, "v b c h w -> (b v) c h w")
    else:
        bounds = [image_size * k // len(views) for k in range(len(views) + 1)]  # strip edges, left to right
        strips = [
            _resized(view, image_size, right - left)
            for view, left, right in zip(views, bounds[:-1], bounds[1:], strict=True)
        ]
        pixels = torch.cat(strips, dim=-1)  # (B, 3, I, I)
    mean = torch.tensor(image_mean, device=pixels.device).view(1, 3, 1, 1)
    std = torch.tensor(image_std, device=pixels.device).view(1, 3, 1, 1)
    return (pixels - mean) / std


# ------------------------------------------------------------------------------------------------------------
# The backbone module
# ------------------------------------------------------------------------------------------------------------
def _load_base_vlm(
    name_or_path: str | None, config: PretrainedConfig | None, dtype: torch.dtype
) -> nn.Module:
    """The VLM base model (no LM head): pretrained by name/path, or randomly initialised from ``config``."""
    if name_or_path is None:
        return AutoModel.from_config(config, dtype=dtype)
    full = AutoModelForImageTextToText.from_pretrained(name_or_path, dtype=dtype)
    if not hasattr(full, "model"):
        raise ValueError(
            f"{name_or_path!r}: expected a transformers image-text-to-text model with a `.model` base"
        )
    return full.model  # drop the LM head: SubgoalVLA never decodes text


class VLMBackbone(nn.Module):
    """A transformers VLM truncated to LLM layer k; returns H[k] and the token padding mask.

    Args:
        name_or_path: Hugging Face id or local directory of a LLaVA-style checkpoint; None builds the tiny
            model.
        layer: k, 1-based LLM layer whose output is returned; None -> m // 2 (paper section 4.1).
        freeze_vision_tower: freeze the vision encoder (no gradients, always eval mode), paper section 5.
        tiny: dimensions of the tiny model (only with ``name_or_path=None``).
        torch_dtype: weight dtype, "float32" | "bfloat16" | "float16" (or a torch.dtype).
        vlm_config: with ``name_or_path=None``, build this architecture (random weights) instead of the tiny
            one; used to size the paper/small architectures on the meta device without downloading anything.
        vision_stem: the tiny tower's patch embedding, "patch" (CLIP's) or "conv" (``vision_stem.ConvStem``);
            None keeps the model's own (pretrained towers).
        camera_layout: how ``prepare_pixel_values`` lays out the cameras, "side_by_side" or "separate".
    """

    def __init__(
        self,
        name_or_path: str | None,
        layer: int | None = None,
        freeze_vision_tower: bool = True,
        tiny: TinyLlavaDims | None = None,
        torch_dtype: str | torch.dtype = "float32",
        vlm_config: PretrainedConfig | None = None,
        vision_stem: str | None = None,
        camera_layout: str = "side_by_side",
    ) -> None:
        super().__init__()
        self.camera_layout = camera_layout
        if name_or_path is not None and (tiny is not None or vlm_config is not None):
            raise ValueError("VLMBackbone: tiny / vlm_config only apply when name_or_path is None")
        if tiny is not None and vlm_config is not None:
            raise ValueError("VLMBackbone: give either tiny dimensions or a vlm_config, not both")
        dtype = _DTYPES[torch_dtype] if isinstance(torch_dtype, str) else torch_dtype
        if name_or_path is None and vlm_config is None:
            vlm_config = build_tiny_llava_config(_required_tiny(tiny))
        self.vlm = _load_base_vlm(name_or_path, vlm_config, dtype)
        if vision_stem == "conv":
            if name_or_path is not None:
                raise ValueError("VLMBackbone: vision_stem='conv' applies to a tiny tower only")
            install_conv_stem(self.vlm.vision_tower, self.vlm.config.vision_config.patch_size)
            self.vlm.vision_tower.to(dtype)
        for part in ("vision_tower", "multi_modal_projector", "language_model"):
            if not hasattr(self.vlm, part):
                raise ValueError(f"{name_or_path!r} is not a LLaVA-style VLM: its base model lacks `{part}`")
        self.num_llm_layers = len(self.vlm.language_model.layers)
        self.layer = self.num_llm_layers // 2 if layer is None else layer
        if not 1 <= self.layer <= self.num_llm_layers:
            raise ValueError(
                f"backbone layer k={layer} must be in [1, {self.num_llm_layers}] for {name_or_path!r}"
            )
        self._truncate_language_model(self.layer)
        self.freeze_vision_tower = freeze_vision_tower
        if freeze_vision_tower:
            self.vlm.vision_tower.requires_grad_(False)
            self.vlm.vision_tower.eval()
        self.hidden_size = self.vlm.config.text_config.hidden_size
        image_stats = (OPENAI_CLIP_MEAN, OPENAI_CLIP_STD)
        if name_or_path is not None:
            processor = AutoImageProcessor.from_pretrained(name_or_path)
            image_stats = (processor.image_mean, processor.image_std)
        self.input_spec = VLMInputSpec.from_config(self.vlm.config, *image_stats)

    def _truncate_language_model(self, k: int) -> None:
        """Keep decoder layers 1..k and drop the final norm, so the LLM output is H[k]."""
        lm = self.vlm.language_model
        lm.layers = lm.layers[:k]
        lm.norm = nn.Identity()
        lm.config.num_hidden_layers = k

    def enable_gradient_checkpointing(self) -> None:
        """Recompute each kept decoder layer in the backward pass instead of storing its activations.

        transformers' own switch (``gradient_checkpointing_enable``), non-reentrant. It acts in training mode
        only, so the frozen vision tower (always in eval mode, no graph) is unaffected. Each layer then keeps
        only its input hidden states; ``docs/memory.md`` has the saving per preset.
        """
        self.vlm.gradient_checkpointing_enable(gradient_checkpointing_kwargs={"use_reentrant": False})

    def train(self, mode: bool = True) -> VLMBackbone:
        """Switch modes but keep a frozen vision tower in eval mode (no dropout/batch-stat updates)."""
        super().train(mode)
        if self.freeze_vision_tower:
            self.vlm.vision_tower.eval()
        return self

    def vision_parameters(self) -> list[nn.Parameter]:
        """Vision encoder parameters (frozen by default: in no optimizer group)."""
        return list(self.vlm.vision_tower.parameters())

    def projector_parameters(self) -> list[nn.Parameter]:
        """Multi-modal projector parameters (learning rate 1e-5, table 8)."""
        return list(self.vlm.multi_modal_projector.parameters())

    def language_model_parameters(self) -> list[nn.Parameter]:
        """Kept LLM parameters: embeddings and layers 1..k (learning rate 2e-5, table 8)."""
        return list(self.vlm.language_model.parameters())

    @property
    def dtype(self) -> torch.dtype:
        """Dtype of the backbone weights."""
        return self.vlm.language_model.get_input_embeddings().weight.dtype

    def prepare_pixel_values(self, views: Sequence[Tensor]) -> Tensor:
        """``prepare_pixel_values`` with this backbone's image size, statistics and camera layout."""
        spec = self.input_spec
        return prepare_pixel_values(
            views, spec.image_size, spec.image_mean, spec.image_std, self.camera_layout
        )

    def forward(
        self, input_ids: Tensor, attention_mask: Tensor, pixel_values: Tensor
    ) -> tuple[Tensor, Tensor]:
        """Hidden states of LLM layer k.

        Args:
            input_ids: (B, S) from ``tokenize_instructions`` (image placeholders included).
            attention_mask: (B, S), 1/True = valid token.
            pixel_values: (B, 3, I, I) from ``prepare_pixel_values`` ((B * V, 3, I, I) with ``separate``).

        Returns:
            hidden (B, S, E) = H[k] and mask (B, S) bool, True = valid.
        """
        out = self.vlm(
            input_ids=input_ids,
            attention_mask=attention_mask.long(),
            pixel_values=pixel_values.to(self.dtype),
            use_cache=False,
        )
        return out.last_hidden_state, attention_mask.bool()
