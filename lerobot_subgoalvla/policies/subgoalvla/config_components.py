"""The nested pieces of :class:`SubgoalVLAConfig` and the values of its presets.

Kept apart from ``configuration_subgoalvla.py`` so that the policy config reads as one page: the backbone, one
proprioceptive cross-attention stack and one DiT head are each a small dataclass (set on the command line with
dotted flags such as ``--policy.planner.depth=4``), and ``PRESET_VALUES`` holds what ``--policy.preset`` fills
in. The paper's values and the choices made where it is inconsistent are documented in
``configuration_subgoalvla``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from lerobot_subgoalvla.config_error import ConfigError


def require_positive(name: str, value: int | float | None) -> None:
    """Raise one line naming ``--policy.<name>`` unless ``value`` is a positive number."""
    if value is None or value <= 0:
        raise ConfigError(f"--policy.{name} must be positive, got {value!r}")


def require_choice(name: str, value: str, allowed: tuple[str, ...]) -> None:
    """Reject ``value`` unless it is one of ``allowed``, naming the flag and the allowed values."""
    if value not in allowed:
        raise ConfigError(f"--policy.{name}={value!r} is not valid; allowed values: {', '.join(allowed)}")


@dataclass(frozen=True)
class TinyLlavaDims:
    """Dimensions of the randomly initialised tiny LLaVA (CLIP vision tower + LLaMA decoder).

    The values come from the preset (``PRESET_VALUES``) through ``BackboneConfig.tiny_dims``; there are no
    defaults here, so the preset table is the one place that sizes a tiny backbone.
    """

    text_hidden_size: int
    text_num_layers: int
    text_num_heads: int
    text_intermediate_size: int
    vision_hidden_size: int
    vision_num_layers: int
    vision_num_heads: int
    image_size: int
    patch_size: int
    vocabulary: tuple[str, ...]


@dataclass
class BackboneConfig:
    """The vision-language backbone whose layer-k hidden states the heads read (paper section 4.1).

    Each field's help is the comment above it: ``--help`` shows it.
    """

    # Hugging Face id or local directory of a LLaVA-architecture checkpoint (`llava-hf/llava-1.5-7b-hf` in the
    # paper). `None` builds a randomly initialised tiny LLaVA from the `text_*`/`vision_*` dimensions below
    # (no download).
    name_or_path: str | None = None
    # k, the LLM layer whose hidden states H[k] feed the cross-attention. `None` means k = m // 2 (m = number
    # of LLM layers), the paper's choice; it is resolved from the loaded model.
    layer: int | None = None
    # keep the vision encoder frozen (paper section 5, appendix C); its parameters are then not in any
    # optimizer group. Unset: frozen, except in `laptop` (a random tower must learn).
    freeze_vision_tower: bool | None = None
    # Tiny architecture (only with name_or_path=None).
    # tiny LLM hidden size d (`name_or_path=None` only; pretrained models bring their own).
    text_hidden_size: int | None = None
    # tiny LLM depth m.
    text_num_layers: int | None = None
    # tiny LLM attention heads.
    text_num_heads: int | None = None
    # tiny LLM MLP width.
    text_intermediate_size: int | None = None
    # tiny vision-encoder width.
    vision_hidden_size: int | None = None
    # tiny vision-encoder depth.
    vision_num_layers: int | None = None
    # tiny vision-encoder attention heads.
    vision_num_heads: int | None = None
    # tiny vision-encoder input size (pixels, square); camera images are resized to it.
    image_size: int | None = None
    # tiny vision-encoder patch size (image_size must be a multiple of it).
    patch_size: int | None = None
    # tiny vision-encoder patch embedding: `patch` (CLIP's one linear map per patch) or `conv` (stride-2 3x3
    # convolutions, then one over the rest of the patch: Xiao et al. 2021; needs an even patch_size).
    vision_stem: str | None = None
    # how the cameras enter the vision tower: `side_by_side` (the paper's: one square image, camera k resized
    # into its k-th vertical strip) or `separate` (one square image per camera, each at the tower's full
    # size: K times the image tokens and the vision cost, no camera squeezed to 1/K of the width).
    camera_layout: str = "side_by_side"
    # words of the tiny tokenizer; lerobot-train fills it from the training dataset's tasks and the
    # instructions its metadata lists, and it is saved with the checkpoint (leave unset).
    vocabulary: list[str] | None = None
    # Tokenisation and precision.
    # instructions are padded/truncated to this many tokens by the preprocessor.
    max_instruction_tokens: int | None = None
    # dtype of the backbone weights (`float32`, `bfloat16`, `float16`); the heads stay float32. Train in
    # float32 with `--policy.dtype=bfloat16` (mixed precision); bf16 weights suit inference only.
    torch_dtype: str | None = None

    @property
    def tiny_architecture_fields(self) -> tuple[str, ...]:
        """Names of the fields that describe the tiny random LLaVA (None for pretrained backbones)."""
        return tuple(f.name for f in dataclasses.fields(TinyLlavaDims))

    @property
    def tiny_only_fields(self) -> tuple[str, ...]:
        """Fields a pretrained backbone must leave unset: the tiny architecture and its patch embedding."""
        return (*self.tiny_architecture_fields, "vision_stem")

    def tiny_dims(self) -> TinyLlavaDims | None:
        """The tiny LLaVA's dimensions; None for a pretrained backbone (``name_or_path`` set)."""
        if self.name_or_path is not None:
            return None
        values = {name: getattr(self, name) for name in self.tiny_architecture_fields}
        if values["vocabulary"] is None:
            raise ConfigError(
                "--policy.backbone.vocabulary is unset: a tiny backbone takes its words from the training "
                "dataset (build the policy with lerobot-train / make_policy(cfg, ds_meta=...)) or this flag"
            )
        return TinyLlavaDims(**{**values, "vocabulary": tuple(values["vocabulary"])})


@dataclass
class CrossAttentionConfig:
    """Proprioceptive cross-attention (PCA, paper Eq. 2): queries from the proprioception, keys/values H[k].

    Its width is the backbone's hidden size d (queries are projected into the vision-language space).

    Each field's help is the comment above it: ``--help`` shows it.
    """

    # stacked pre-norm cross-attention + MLP blocks (3 in table 5).
    num_layers: int | None = None
    # attention heads (8 in table 5); must divide the backbone hidden size.
    num_heads: int | None = None
    # MLP width as a multiple of d.
    mlp_ratio: float = 4.0
    # dropout on attention weights and MLP outputs (the paper uses dropout, rate not given).
    dropout: float | None = None

    def validate(self, name: str) -> None:
        """Reject bad values with one line naming the flag ``--policy.<name>.<field>`` and what is allowed."""
        require_positive(f"{name}.num_layers", self.num_layers)
        require_positive(f"{name}.num_heads", self.num_heads)
        require_positive(f"{name}.mlp_ratio", self.mlp_ratio)
        if not 0.0 <= self.dropout < 1.0:
            raise ConfigError(f"--policy.{name}.dropout must be in [0, 1), got {self.dropout}")


@dataclass
class DiTHeadConfig:
    """One diffusion-transformer head: the subgoal planner or the action generator (appendix B, tables 6-8).

    Each field's help is the comment above it: ``--help`` shows it.
    """

    # DiT width (768 for DiT-B).
    hidden_size: int | None = None
    # number of adaLN-zero DiT blocks (12 for DiT-B).
    depth: int | None = None
    # self-attention heads (12 for DiT-B, table 5).
    num_heads: int | None = None
    # MLP width as a multiple of hidden_size.
    mlp_ratio: float = 4.0
    # T, diffusion timesteps of the squared-cosine schedule (8, tables 6-7).
    num_train_timesteps: int = 8
    # DDIM sampling steps (<= num_train_timesteps; see the module docstring).
    num_inference_steps: int = 8
    # classifier-free guidance scale s (1.0 disables CFG; the paper uses s > 1 for the planner). Unset: 1.5
    # for the planner, 1.0 for the generator (module docstring).
    guidance_scale: float | None = None
    # probability of replacing the conditioning by the learned null condition during training (0.1, appendix
    # B.1); enables CFG.
    label_dropout: float = 0.1
    # lambda of the L2 penalty on the predicted noise (0.001, appendix B.1).
    l2_weight: float = 0.001
    # timesteps sampled per training example ("repeated diffusion steps" 8, table 8; 4 in `laptop`, where the
    # heads dominate a CPU update).
    repeated_diffusion_steps: int | None = None
    # bound on DDIM's estimate of the clean sample, in normalised units (diffusers `clip_sample_range`).
    # Needed: the 8-step squared-cosine schedule ends at alpha_bar = 3.7e-5, so the first DDIM step divides
    # the noise-prediction error by sqrt(alpha_bar) (163x). Unset: 1.0 when the head's target is MIN_MAX-
    # normalised (it then lies in [-1, 1]: actions by default), else 4.0 (z-scores: the trace under the
    # default MEAN_STD state normalisation). Added by policy-core (model.py resolves it).
    clip_sample_range: float | None = None

    def validate(self, name: str) -> None:
        """Reject bad values with one line naming the flag ``--policy.<name>.<field>`` and what is allowed."""
        for attr in ("hidden_size", "depth", "num_heads", "mlp_ratio", "num_train_timesteps"):
            require_positive(f"{name}.{attr}", getattr(self, attr))
        require_positive(f"{name}.num_inference_steps", self.num_inference_steps)
        require_positive(f"{name}.repeated_diffusion_steps", self.repeated_diffusion_steps)
        if self.clip_sample_range is not None:
            require_positive(f"{name}.clip_sample_range", self.clip_sample_range)
        if self.hidden_size % self.num_heads != 0:
            raise ConfigError(
                f"--policy.{name}.hidden_size={self.hidden_size} must be divisible by "
                f"--policy.{name}.num_heads={self.num_heads}"
            )
        if self.num_inference_steps > self.num_train_timesteps:
            raise ConfigError(
                f"--policy.{name}.num_inference_steps={self.num_inference_steps} must be <= "
                f"--policy.{name}.num_train_timesteps={self.num_train_timesteps} (DDIM skips timesteps, it "
                "cannot add any)"
            )
        if self.guidance_scale < 1.0:
            raise ConfigError(
                f"--policy.{name}.guidance_scale must be >= 1 (1 disables CFG), got {self.guidance_scale}"
            )
        if not 0.0 <= self.label_dropout < 1.0:
            raise ConfigError(f"--policy.{name}.label_dropout must be in [0, 1), got {self.label_dropout}")
        if self.l2_weight < 0:
            raise ConfigError(f"--policy.{name}.l2_weight must be >= 0, got {self.l2_weight}")


# ------------------------------------------------------------------------------------------------------------
# Preset values: (dataclass attribute on SubgoalVLAConfig, field) -> value; "recipe" holds fields of the
# config itself. Only fields that default to None are filled, and only where they are still None.
# ------------------------------------------------------------------------------------------------------------
_PAPER_RECIPE = {  # table 8 and section 5
    "optimizer_lr_projector": 1e-5,
    "optimizer_lr_llm": 2e-5,
    "optimizer_lr_heads": 1e-4,
    "scheduler_warmup_ratio": 0.05,
    "scheduler_decay_lr": 3e-6,
}
#: Short CPU runs (minutes, not days): 10x the paper's head rate, every backbone
#: part at 3e-4 (a random backbone
#: must learn from scratch), a short warmup and a cosine to 1 % so the last steps refine rather than jitter.
_SHORT_RUN_RECIPE = {
    "optimizer_lr_projector": 3e-4,
    "optimizer_lr_llm": 3e-4,
    "optimizer_lr_heads": 1e-3,
    "scheduler_warmup_ratio": 0.02,
    "scheduler_decay_lr": 1e-5,
}

PRESET_VALUES: dict[str, dict[str, dict[str, Any]]] = {
    "tiny": {
        "recipe": {**_SHORT_RUN_RECIPE, "dtype": "float32"},
        "backbone": {
            "name_or_path": None,
            "text_hidden_size": 32,
            "text_num_layers": 4,
            "text_num_heads": 4,
            "text_intermediate_size": 64,
            "vision_hidden_size": 32,
            "vision_num_layers": 2,
            "vision_num_heads": 4,
            "image_size": 32,
            "patch_size": 8,
            "vision_stem": "patch",
            "max_instruction_tokens": 32,
            "torch_dtype": "float32",
            "freeze_vision_tower": True,
        },
        "planner": {
            "hidden_size": 32,
            "depth": 2,
            "num_heads": 2,
            "guidance_scale": 1.5,
            "repeated_diffusion_steps": 8,
        },
        "generator": {
            "hidden_size": 32,
            "depth": 2,
            "num_heads": 2,
            "guidance_scale": 1.0,
            "repeated_diffusion_steps": 8,
        },
        "planner_attention": {"num_layers": 1, "num_heads": 2, "dropout": 0.0},
        "generator_attention": {"num_layers": 1, "num_heads": 2, "dropout": 0.0},
    },
    "laptop": {
        "recipe": {**_SHORT_RUN_RECIPE, "dtype": "float32"},
        "backbone": {
            "name_or_path": None,
            "text_hidden_size": 64,
            "text_num_layers": 4,
            "text_num_heads": 4,
            "text_intermediate_size": 256,
            "vision_hidden_size": 64,
            "vision_num_layers": 3,
            "vision_num_heads": 4,
            "image_size": 80,
            "patch_size": 10,
            "vision_stem": "patch",
            "max_instruction_tokens": 24,
            "torch_dtype": "float32",
            "freeze_vision_tower": False,
        },
        "planner": {
            "hidden_size": 64,
            "depth": 3,
            "num_heads": 4,
            "guidance_scale": 1.5,
            "repeated_diffusion_steps": 4,
        },
        "generator": {
            "hidden_size": 64,
            "depth": 3,
            "num_heads": 4,
            "guidance_scale": 1.0,
            "repeated_diffusion_steps": 4,
        },
        "planner_attention": {"num_layers": 2, "num_heads": 4, "dropout": 0.0},
        "generator_attention": {"num_layers": 2, "num_heads": 4, "dropout": 0.0},
    },
    "small": {
        "recipe": {**_PAPER_RECIPE, "dtype": "bfloat16"},
        "backbone": {
            "name_or_path": "llava-hf/llava-interleave-qwen-0.5b-hf",
            "max_instruction_tokens": 64,
            "torch_dtype": "float32",
            "freeze_vision_tower": True,
        },
        "planner": {
            "hidden_size": 384,
            "depth": 12,
            "num_heads": 6,
            "guidance_scale": 1.5,
            "repeated_diffusion_steps": 8,
        },
        "generator": {
            "hidden_size": 384,
            "depth": 12,
            "num_heads": 6,
            "guidance_scale": 1.0,
            "repeated_diffusion_steps": 8,
        },
        "planner_attention": {"num_layers": 3, "num_heads": 8, "dropout": 0.1},
        "generator_attention": {"num_layers": 3, "num_heads": 8, "dropout": 0.1},
    },
    "paper": {
        "recipe": {**_PAPER_RECIPE, "dtype": "bfloat16"},
        "backbone": {
            "name_or_path": "llava-hf/llava-1.5-7b-hf",
            "max_instruction_tokens": 64,
            "torch_dtype": "float32",
            "freeze_vision_tower": True,
        },
        "planner": {
            "hidden_size": 768,
            "depth": 12,
            "num_heads": 12,
            "guidance_scale": 1.5,
            "repeated_diffusion_steps": 8,
        },
        "generator": {
            "hidden_size": 768,
            "depth": 12,
            "num_heads": 12,
            "guidance_scale": 1.0,
            "repeated_diffusion_steps": 8,
        },
        "planner_attention": {"num_layers": 3, "num_heads": 8, "dropout": 0.1},
        "generator_attention": {"num_layers": 3, "num_heads": 8, "dropout": 0.1},
    },
}
