"""Configuration of the SubgoalVLA policy (paper section 4, appendices B and C).

One typed dataclass, :class:`SubgoalVLAConfig`, registered with LeRobot as ``--policy.type=subgoalvla``. Its
nested dataclasses (:class:`BackboneConfig`, :class:`CrossAttentionConfig`, :class:`DiTHeadConfig`) are set on
the command line with dotted flags (``--policy.planner.depth=4``).

Presets. ``--policy.preset=tiny|laptop|small|paper`` chooses the architecture (default ``laptop``, the
smallest that learns from its cameras). Fields that depend on the preset
default to ``None`` and :meth:`SubgoalVLAConfig.__post_init__` fills every ``None`` from the chosen preset,
so an explicit flag always wins over the preset and a saved ``config.json`` holds every value (reloading it
rebuilds exactly the same model):

- ``paper``: the values of the paper (tables 5-8): LLaVA-1.5-7B backbone, DiT-B heads (768 wide, 12 deep,
  12 heads), proprioceptive cross-attention (PCA) of 3 layers and 8 heads, features from layer k = m // 2.
- ``small``: a real pretrained LLaVA-architecture VLM of about 0.9B parameters
  (``llava-hf/llava-interleave-qwen-0.5b-hf``: SigLIP-so400m + Qwen1.5-0.5B) with DiT-S heads (384 x 12 x 6),
  the vision tower frozen; computed peak per GPU at batch 32: 39 GB, 17 GB with gradient checkpointing
  (docs/memory.md).
- ``laptop``: a random LLaVA-architecture model (no download) that learns CALVIN's fixture tasks in ~20
  minutes on 2 CPU cores: 80 px input, a trainable vision tower (a frozen random one cannot see), small DiT
  heads and a short-run recipe (heads 1e-3, the rest 3e-4, 2 % warmup, cosine to 1 %). The demo uses it.
- ``tiny``: the same kind of model at the smallest sizes (32 px, 32 wide, a frozen random vision tower: it
  cannot use its cameras); for the unit tests and smoke runs only.

Precision: ``small``/``paper`` train in bf16 mixed precision (float32 weights, ``dtype=bfloat16`` = accelerate
autocast in ``lerobot-train``); bf16 weights would round most lr-2e-5 updates away (docs/policy.md). LeRobot
0.6.1 sets the autocast from ``dtype``; LeRobot main only from ``--accelerator.mixed_precision=bf16``, and a
training step without it stops with that flag in its message (docs/lerobot_versions.md).

Where the paper is inconsistent (DiT heads 8 or 12, 8 diffusion steps vs DDIM 10, the executed part of a
chunk, the guidance scales) the config follows the more specific statement; docs/model.md lists each choice.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import NormalizationMode, PolicyFeature, PreTrainedConfig
from lerobot.optim import AdamWConfig

from lerobot_subgoalvla.config_error import ConfigError
from lerobot_subgoalvla.policies.subgoalvla.config_components import (
    PRESET_VALUES,
    BackboneConfig,
    CrossAttentionConfig,
    DiTHeadConfig,
    require_choice,
    require_positive,
)
from lerobot_subgoalvla.policies.subgoalvla.dataset_features import DatasetFitting
from lerobot_subgoalvla.policies.subgoalvla.schedule import TwoStageCosineSchedulerConfig

PRESETS = ("tiny", "laptop", "small", "paper")
FEATURE_AGGREGATIONS = ("proprio_xattn", "mean", "max", "attn")
STAGES = ("stage1", "stage2")
#: ``PRESET_VALUES[...]["recipe"]`` fills attributes of SubgoalVLAConfig itself (not of a nested dataclass).
RECIPE = "recipe"
TORCH_DTYPES = ("float32", "bfloat16", "float16")
VISION_STEMS = ("patch", "conv")
CAMERA_LAYOUTS = ("side_by_side", "separate")


@PreTrainedConfig.register_subclass("subgoalvla")
@dataclass
class SubgoalVLAConfig(PreTrainedConfig, DatasetFitting):
    """SubgoalVLA: VLM backbone -> proprioceptive cross-attention -> DiT planner -> DiT action generator.

    How it fits a dataset or env (cameras, state, window, angles) is ``DatasetFitting``'s
    (``dataset_features.py``). Each field's help is the comment above it: ``--help`` shows it.
    """

    # LeRobot's: observation steps per sample; SubgoalVLA reads one frame (its history is a dataset column).
    n_obs_steps: int = 1
    # LeRobot's: filled from the dataset by lerobot-train (cameras, state, history, trace); leave unset.
    input_features: dict[str, PolicyFeature] | None = field(default_factory=dict)
    # LeRobot's: filled from the dataset by lerobot-train (the action); leave unset.
    output_features: dict[str, PolicyFeature] | None = field(default_factory=dict)
    # LeRobot's: Hub repo id the trained policy is pushed to (with --policy.push_to_hub=true).
    repo_id: str | None = None
    # architecture and training-recipe preset: tiny | laptop | small | paper (module docstring); flags win.
    # laptop (the default) is the smallest that learns from its cameras; tiny is for tests only.
    preset: str = "laptop"
    # the vision-language backbone (:class:`BackboneConfig`).
    backbone: BackboneConfig = field(default_factory=BackboneConfig)
    # PCA producing the planner's conditioning f^{c,g} from the state history.
    planner_attention: CrossAttentionConfig = field(default_factory=CrossAttentionConfig)
    # PCA producing the generator's conditioning f^{c,a} from [history, trace].
    generator_attention: CrossAttentionConfig = field(default_factory=CrossAttentionConfig)
    # DiT subgoal planner psi (appendix B.1).
    planner: DiTHeadConfig = field(default_factory=DiTHeadConfig)
    # DiT action generator phi (appendix B.2).
    generator: DiTHeadConfig = field(default_factory=DiTHeadConfig)

    # cameras the policy reads, in this order (their views sit side by side, left to right, in the vision
    # tower's square image); unset: every camera of the dataset, in the order of its features.
    camera_keys: list[str] | None = None
    # h, proprioceptive states in S_t (15, tables 6-7); must match the dataset's `observation.state_history`.
    state_history_len: int = 15
    # M, trace steps the planner predicts (8, appendix A); 1 is the "w/o ST" ablation (the first trace step
    # only). The dataset's trace must have at least this many steps.
    subgoal_trace_len: int = 8
    # frames between consecutive history (and trace) states; unset: the dataset's window (1 without one).
    # The policy rebuilds its history at inference with it.
    state_stride: int | None = None
    # frames from t to the first trace state; unset: the dataset's window. A value that differs from the
    # dataset's is refused (the trace columns were cut with the dataset's).
    subgoal_trace_start: int | None = None
    # N, actions predicted per chunk (15, table 7).
    chunk_size: int = 15
    # actions executed from each predicted chunk before predicting the next one.
    n_action_steps: int = 8

    # how vision-language tokens are aggregated (table 4): `proprio_xattn` (PCA, the method), `mean` / `max`
    # (top-k tokens by similarity to the mean / by norm), `attn` (learned query scores, top-k); appendix D.1.
    feature_aggregation: str = "proprio_xattn"
    # k tokens kept by the `mean`/`max`/`attn` aggregations.
    aggregation_top_k: int = 32
    # False is the "w/o SP" ablation: no planner, the generator conditions on the state history and the
    # vision-language features only.
    use_planner: bool = True
    # weight of an auxiliary stage-I loss (not in the paper): regress the dataset's
    # `observation.environment_state` (object poses) from the vision-language features, so that the vision
    # tower learns to see what the actions depend on (environment_head.py); 0 switches it off. Training only.
    environment_state_weight: float = 0.0

    # training stage at step 0: `stage1` (generator conditioned on ground-truth traces, everything trained) or
    # `stage2` (generator conditioned on traces sampled from the planner, backbone frozen). Start a stage II
    # run from a stage I checkpoint with `--policy.path=<ckpt> --policy.stage=stage2`.
    stage: str = "stage1"
    # with `stage=stage1`, the optimizer step at which the same run switches to stage II (None: never). The
    # policy counts steps in a saved buffer, so `--resume=true` continues in the right stage. With
    # `stage=stage2` every step is stage II, so a stage I checkpoint that had a switch step can be continued
    # with `--policy.stage=stage2` as it is.
    stage2_start_step: int | None = None

    # learning rate of the vision-to-language projector (1e-5, table 8), and of an unfrozen vision tower.
    optimizer_lr_projector: float | None = None
    # learning rate of the LLM (2e-5, table 8).
    optimizer_lr_llm: float | None = None
    # learning rate of the PCA modules and both DiT heads (1e-4, table 8); also the scheduler's peak.
    optimizer_lr_heads: float | None = None
    # AdamW betas.
    optimizer_betas: tuple[float, float] = (0.9, 0.999)
    # AdamW epsilon.
    optimizer_eps: float = 1e-8
    # AdamW weight decay (0.01, table 8).
    optimizer_weight_decay: float = 0.01
    # gradient-norm clipping threshold (not given in the paper).
    optimizer_grad_clip_norm: float = 1.0
    # linear-warmup fraction of each training stage (0.05, table 8).
    scheduler_warmup_ratio: float | None = None
    # the heads' learning rate at the end of each stage's cosine (3e-6, section 5); the other groups decay by
    # the same factor. A stage I -> II switch restarts warmup and cosine (`schedule.py`).
    scheduler_decay_lr: float | None = None
    # training precision: `bfloat16` = bf16 mixed precision (float32 weights, bf16 autocast), `float32` = full
    # precision. LeRobot 0.6.1's lerobot-train applies it; later ones need --accelerator.mixed_precision=bf16.
    dtype: str | None = None
    # recompute the activations of the LLM layers, cross-attention and DiT blocks in the backward pass instead
    # of storing them: same loss and gradients, one extra forward of those blocks, far less memory
    # (docs/memory.md).
    gradient_checkpointing: bool = False
    # indices of wrapping angles in `observation.state` (CALVIN's converter records 3, 4, 5); unset: the
    # dataset's metadata, or none. `[]` switches a dataset's angles off. Other dims are z-scored.
    state_angle_dims: tuple[int, ...] | None = None
    # the orientation those angles are measured from, radians, one per angle dim (CALVIN: pi, 0, 0); the
    # model sees `wrap(angle - home)`, continuous wherever the arm goes. Unset: the dataset's.
    state_angle_home: tuple[float, ...] | None = None
    # radians per normalised unit of those angles.
    state_angle_scale: float = 1.0

    # normalisation per feature type for LeRobot's normaliser. `STATE` must stay `IDENTITY`: the
    # proprioception (state, history, trace) is normalised by the policy's own step with the state's
    # statistics and continuous angles (`proprio_normalization.py`).
    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.IDENTITY,
            "ENV": NormalizationMode.IDENTITY,
            "ACTION": NormalizationMode.MIN_MAX,
        }
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        require_choice("preset", self.preset, PRESETS)
        self._fill_from_preset()
        self._validate()

    # Presets ------------------------------------------------------------------------------------------------
    def _fill_from_preset(self) -> None:
        """Fill every still-``None`` preset field from ``self.preset``; explicit values win."""
        values = PRESET_VALUES[self.preset]
        pretrained = self.backbone.name_or_path is not None
        for attribute, defaults in values.items():
            sub = self if attribute == RECIPE else getattr(self, attribute)
            for name, value in defaults.items():
                # A user-chosen pretrained backbone brings its own architecture: never add tiny dimensions.
                if attribute == "backbone" and pretrained and name in sub.tiny_only_fields:
                    continue
                if name == "name_or_path":
                    continue  # None is meaningful (tiny); filled below only when the preset is pretrained
                if getattr(sub, name) is None:
                    setattr(sub, name, value)
        if self.backbone.name_or_path is None and values["backbone"]["name_or_path"] is not None:
            self.backbone.name_or_path = values["backbone"]["name_or_path"]

    # Validation ---------------------------------------------------------------------------------------------
    def _validate(self) -> None:
        require_choice("feature_aggregation", self.feature_aggregation, FEATURE_AGGREGATIONS)
        require_choice("stage", self.stage, STAGES)
        require_choice("backbone.torch_dtype", self.backbone.torch_dtype, TORCH_DTYPES)
        require_choice("backbone.camera_layout", self.backbone.camera_layout, CAMERA_LAYOUTS)
        require_choice("dtype", self.dtype, TORCH_DTYPES)
        if self.normalization_mapping.get("STATE") != NormalizationMode.IDENTITY:
            raise ConfigError(
                "--policy.normalization_mapping must keep STATE: IDENTITY; SubgoalVLA normalises the "
                "proprioception itself (state statistics, continuous angles)"
            )
        if (self.state_angle_dims is None) != (self.state_angle_home is None) or len(
            self.state_angle_dims or ()
        ) != len(self.state_angle_home or ()):
            raise ConfigError(
                f"--policy.state_angle_home needs one value per --policy.state_angle_dims entry "
                f"(dims {self.state_angle_dims}, home {self.state_angle_home})"
            )
        if self.state_angle_dims is not None and any(d < 0 for d in self.state_angle_dims):
            raise ConfigError(f"--policy.state_angle_dims must be >= 0, got {list(self.state_angle_dims)}")
        for name in ("state_stride", "subgoal_trace_start"):
            value = getattr(self, name)
            if value is not None and value < (1 if name == "state_stride" else 0):
                raise ConfigError(f"--policy.{name} must be >= {int(name == 'state_stride')}, got {value}")
        if self.camera_keys is not None and not self.camera_keys:
            raise ConfigError("--policy.camera_keys must name at least one camera, or be left unset for all")
        require_positive("state_angle_scale", self.state_angle_scale)
        for name in ("state_history_len", "subgoal_trace_len", "chunk_size", "n_action_steps"):
            require_positive(name, getattr(self, name))
        require_positive("aggregation_top_k", self.aggregation_top_k)
        require_positive("backbone.max_instruction_tokens", self.backbone.max_instruction_tokens)
        if self.n_action_steps > self.chunk_size:
            raise ConfigError(
                f"--policy.n_action_steps={self.n_action_steps} must be <= "
                f"--policy.chunk_size={self.chunk_size}"
            )
        if self.environment_state_weight < 0:
            raise ConfigError(
                f"--policy.environment_state_weight must be >= 0 (0 switches the loss off), got "
                f"{self.environment_state_weight}"
            )
        if self.stage2_start_step is not None and self.stage2_start_step < 0:
            raise ConfigError(f"--policy.stage2_start_step must be >= 0, got {self.stage2_start_step}")
        if not self.use_planner and (self.stage == "stage2" or self.stage2_start_step is not None):
            raise ConfigError(
                "--policy.use_planner=false (w/o SP) has no stage II: drop --policy.stage/stage2_start_step"
            )
        self._validate_backbone()
        for name in ("planner", "generator"):
            getattr(self, name).validate(name)
        for name in ("planner_attention", "generator_attention"):
            getattr(self, name).validate(name)
        for name in (
            "optimizer_lr_projector",
            "optimizer_lr_llm",
            "optimizer_lr_heads",
            "scheduler_decay_lr",
        ):
            require_positive(name, getattr(self, name))
        if not 0.0 <= self.scheduler_warmup_ratio < 1.0:
            raise ConfigError(
                f"--policy.scheduler_warmup_ratio must be in [0, 1), got {self.scheduler_warmup_ratio}"
            )

    def _validate_backbone(self) -> None:
        bb = self.backbone
        if bb.name_or_path is None:
            for name in bb.tiny_architecture_fields:
                if name == "vocabulary":
                    continue  # filled from the training dataset when the policy is built
                require_positive(f"backbone.{name}", getattr(bb, name))
            if bb.image_size % bb.patch_size != 0:
                raise ConfigError(
                    f"--policy.backbone.image_size={bb.image_size} must be a multiple of "
                    f"--policy.backbone.patch_size={bb.patch_size}"
                )
            require_choice("backbone.vision_stem", bb.vision_stem, VISION_STEMS)
            if bb.vision_stem == "conv" and bb.patch_size % 2 != 0:
                raise ConfigError(
                    f"--policy.backbone.vision_stem=conv needs an even --policy.backbone.patch_size, "
                    f"got {bb.patch_size}"
                )
            for prefix in ("text", "vision"):
                hidden, heads = getattr(bb, f"{prefix}_hidden_size"), getattr(bb, f"{prefix}_num_heads")
                if hidden % heads != 0:
                    raise ConfigError(
                        f"--policy.backbone.{prefix}_hidden_size={hidden} must be divisible by "
                        f"--policy.backbone.{prefix}_num_heads={heads}"
                    )
            if bb.layer is not None and not 1 <= bb.layer <= bb.text_num_layers:
                raise ConfigError(
                    f"--policy.backbone.layer={bb.layer} must be in [1, {bb.text_num_layers}] "
                    f"(the tiny LLM has {bb.text_num_layers} layers); leave it unset for m // 2"
                )
        else:
            given = [name for name in bb.tiny_only_fields if getattr(bb, name) is not None]
            if given:
                raise ConfigError(
                    f"--policy.backbone.{given[0]} only applies to the tiny backbone (name_or_path unset); "
                    f"{bb.name_or_path!r} brings its own architecture"
                )
            if bb.layer is not None and bb.layer < 1:
                raise ConfigError(f"--policy.backbone.layer must be >= 1, got {bb.layer}")

    # LeRobot contract
    def validate_features(self) -> None:
        """LeRobot's hook: cameras, state and action exist and fit (``DatasetFitting.check_features``)."""
        self.check_features()

    # -----------------------------------------------------------------------------------------
    @property
    def observation_delta_indices(self) -> None:
        """No observation deltas: the history is precomputed (a delta would decode every camera h times)."""
        return None

    @property
    def action_delta_indices(self) -> list[int]:
        """The action chunk A_t = a_t .. a_{t+N-1}."""
        return list(range(self.chunk_size))

    @property
    def reward_delta_indices(self) -> None:
        return None

    def get_optimizer_preset(self) -> AdamWConfig:
        """AdamW; per-group learning rates come from ``SubgoalVLAPolicy.get_optim_params``."""
        return AdamWConfig(
            lr=self.optimizer_lr_heads,
            betas=self.optimizer_betas,
            eps=self.optimizer_eps,
            weight_decay=self.optimizer_weight_decay,
            grad_clip_norm=self.optimizer_grad_clip_norm,
        )

    def get_scheduler_preset(self) -> TwoStageCosineSchedulerConfig:
        """Linear warmup, then cosine decay (appendix C), restarted for stage II (``schedule.py``)."""
        return TwoStageCosineSchedulerConfig(
            warmup_ratio=self.scheduler_warmup_ratio,
            final_ratio=self.scheduler_decay_lr / self.optimizer_lr_heads,
            stage2_start_step=self.stage2_start_step if self.stage == "stage1" else None,
        )

    def stage_at(self, step: int) -> str:
        """The training stage in force at optimizer step ``step`` (0-based count of finished updates)."""
        if self.stage2_start_step is not None and step >= self.stage2_start_step:
            return "stage2"
        return self.stage


__all__ = [
    "BackboneConfig",
    "CrossAttentionConfig",
    "DiTHeadConfig",
    "SubgoalVLAConfig",
]
