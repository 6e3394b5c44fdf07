"""SubgoalVLAModel: the math-only core of the policy (paper section 4, appendix B; docs/model.md).

::

    cameras + instruction --VLMBackbone--> H[k], mask                                (B, S, E)
    S_t --planner aggregator (PCA, eq. 2)--> f^{c,g}                                 (B, h, E)
    planner DiT psi + DDIM --> subgoal trace G_hat                                    (B, M, p)
    [S_t, G] --generator aggregator (PCA)--> f^{c,a}                                  (B, h+M, E)
    generator DiT phi + DDIM --> action chunk A_hat                                   (B, N, A)

The backbone runs once per chunk (``encode``); both heads read the same H[k]. Two-stage training (section
4.3): stage I conditions the generator on the ground-truth trace G (everything trains); stage II conditions it
on a trace the planner samples without gradient, and the backbone runs under ``no_grad`` (frozen) while both
heads keep training. Ablations are configuration: ``feature_aggregation`` (table 4) swaps the aggregator,
``use_planner=False`` ("w/o SP", table 3) drops the planner so the generator queries come from S_t alone,
``subgoal_trace_len=1`` ("w/o ST") keeps only the first trace step. ``environment_state_weight > 0`` adds an
auxiliary stage-I loss (not in the paper, ``environment_head.py``) that reads the dataset's environment state
back from H[k].

The batch is already normalised by the processor (state, history and trace share the state statistics; actions
use their own). Cameras (any number, in the config's order) arrive in [0, 1] and are laid side by side,
resized and normalised here for the vision tower (on the device).

Dimension legend: ``B`` batch, ``h`` history steps, ``M`` trace steps, ``p`` proprio dim, ``N`` chunk size,
``A`` action dim, ``S`` VLM tokens, ``E`` VLM hidden size (= cross-attention width); the package's legend
(``__init__.py``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
from lerobot.configs import FeatureType, NormalizationMode
from lerobot.utils.constants import OBS_LANGUAGE_ATTENTION_MASK, OBS_LANGUAGE_TOKENS
from torch import Tensor, nn

from lerobot_subgoalvla.contract.keys import (
    ACTION_IS_PAD_KEY,
    ACTION_KEY,
    ENV_STATE_KEY,
    STATE_HISTORY_KEY,
    STATE_KEY,
    SUBGOAL_TRACE_KEY,
)
from lerobot_subgoalvla.policies.subgoalvla.backbone import VLMBackbone
from lerobot_subgoalvla.policies.subgoalvla.configuration_subgoalvla import (
    CrossAttentionConfig,
    DiTHeadConfig,
    SubgoalVLAConfig,
)
from lerobot_subgoalvla.policies.subgoalvla.diffusion import DiffusionObjective
from lerobot_subgoalvla.policies.subgoalvla.dit import DiT
from lerobot_subgoalvla.policies.subgoalvla.environment_head import EnvironmentStateHead
from lerobot_subgoalvla.policies.subgoalvla.proprio_attention import build_aggregator


def _objective(head: DiTHeadConfig, target_normalization: NormalizationMode) -> DiffusionObjective:
    """The head's diffusion objective; an unset clip range follows the target's normalisation (1 for
    MIN_MAX)."""
    clip = head.clip_sample_range
    if clip is None:
        clip = 1.0 if target_normalization == NormalizationMode.MIN_MAX else 4.0
    return DiffusionObjective(
        num_train_timesteps=head.num_train_timesteps,
        num_inference_steps=head.num_inference_steps,
        guidance_scale=head.guidance_scale,
        repeats=head.repeated_diffusion_steps,
        l2_weight=head.l2_weight,
        cond_dropout_prob=head.label_dropout,
        clip_sample_range=clip,
    )


@contextlib.contextmanager
def _eval_mode(*modules: nn.Module) -> Iterator[None]:
    """Put ``modules`` in eval mode for the block and restore each one's previous mode."""
    modes = [module.training for module in modules]
    for module in modules:
        module.eval()
    try:
        yield
    finally:
        for module, mode in zip(modules, modes, strict=True):
            module.train(mode)


def _dit(head: DiTHeadConfig, input_dim: int, cond_dim: int) -> DiT:
    return DiT(
        input_dim,
        cond_dim,
        hidden_dim=head.hidden_size,
        depth=head.depth,
        num_heads=head.num_heads,
        mlp_ratio=head.mlp_ratio,
    )


class SubgoalVLAModel(nn.Module):
    """Backbone + two aggregators + two DiT heads + their diffusion objectives, built from a SubgoalVLAConfig.

    Args:
        config: the policy config; ``input_features[observation.state]`` gives p, ``action_feature`` gives A.
        backbone: an already built backbone to use instead of building ``config.backbone`` (e.g. an
            architecture instantiated on the meta device by the benchmark); None builds it from the config.
    """

    def __init__(self, config: SubgoalVLAConfig, backbone: VLMBackbone | None = None) -> None:
        super().__init__()
        self.config = config
        bb = config.backbone
        if backbone is None:
            backbone = VLMBackbone(
                bb.name_or_path,
                bb.layer,
                bb.freeze_vision_tower,
                bb.tiny_dims(),
                bb.torch_dtype,
                vision_stem=bb.vision_stem,
                camera_layout=bb.camera_layout,
            )
        self.backbone = backbone
        self.camera_keys = config.image_features_in_order  # the views' left-to-right order is learned
        self.state_dim = config.input_features[STATE_KEY].shape[-1]
        self.action_dim = config.action_feature.shape[-1]
        width = self.backbone.hidden_size  # PCA works in the vision-language space (paper 4.1, table 5)
        h, m = config.state_history_len, config.subgoal_trace_len
        self.planner_aggregator: nn.Module | None = None
        self.planner: DiT | None = None
        if config.use_planner:
            self.planner_aggregator = self._aggregator(config.planner_attention, h, width)
            self.planner = _dit(config.planner, self.state_dim, width)
        generator_queries = h + m if config.use_planner else h
        self.generator_aggregator = self._aggregator(config.generator_attention, generator_queries, width)
        self.generator = _dit(config.generator, self.action_dim, width)
        self.environment_head: EnvironmentStateHead | None = None
        if config.environment_state_weight > 0:
            environment_dim = config.input_features[ENV_STATE_KEY].shape[-1]
            heads = config.generator_attention.num_heads
            self.environment_head = EnvironmentStateHead(width, heads, environment_dim)
        if config.gradient_checkpointing:
            self.enable_gradient_checkpointing()
        norms = config.normalization_mapping
        self.planner_objective = _objective(config.planner, norms[FeatureType.STATE.value])  # trace = states
        self.generator_objective = _objective(config.generator, norms[FeatureType.ACTION.value])

    def enable_gradient_checkpointing(self) -> None:
        """Activation checkpointing of the kept LLM layers, the cross-attention blocks and the DiT blocks.

        Trades one extra forward pass of those blocks for storing only their inputs (``docs/memory.md``);
        the loss and gradients are the same. The pooling ablations have no blocks to checkpoint.
        """
        self.backbone.enable_gradient_checkpointing()
        for module in (self.planner_aggregator, self.generator_aggregator, self.planner, self.generator):
            if module is not None and hasattr(module, "gradient_checkpointing"):
                module.gradient_checkpointing = True

    def _aggregator(self, attn: CrossAttentionConfig, num_queries: int, width: int) -> nn.Module:
        # The aggregator works at the VLM's width E (its features are the DiT's conditioning tokens).
        return build_aggregator(
            self.config.feature_aggregation,
            proprio_dim=self.state_dim,
            num_queries=num_queries,
            encoder_dim=width,
            dim=width,
            attention=attn,
            top_k=self.config.aggregation_top_k,
        )

    def head_parameters(self) -> list[nn.Parameter]:
        """Aggregators, DiT heads and the auxiliary environment head (learning rate 1e-4, table 8); the
        backbone groups live on ``backbone``."""
        heads = [
            self.planner_aggregator,
            self.planner,
            self.generator_aggregator,
            self.generator,
            self.environment_head,
        ]
        return [p for module in heads if module is not None for p in module.parameters()]

    # --------------------------------------------------------------------------------------------------------
    def encode(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        """Run the backbone once: layer-k states of image + instruction tokens.

        Args:
            batch: the policy's cameras (B, 3, H_k, W_k) in [0, 1] (``config.image_features_in_order``),
                ``observation.language.tokens`` (B, S) and ``observation.language.attention_mask`` (B, S).

        Returns:
            hidden (B, S, E) float32 and mask (B, S) bool (True = valid).
        """
        pixels = self.backbone.prepare_pixel_values([batch[key] for key in self.camera_keys])
        hidden, mask = self.backbone(batch[OBS_LANGUAGE_TOKENS], batch[OBS_LANGUAGE_ATTENTION_MASK], pixels)
        return hidden.float(), mask  # heads run in float32 whatever the backbone dtype

    def _generator_queries(self, history: Tensor, trace: Tensor | None) -> Tensor:
        """``[S_t, G]`` (B, h+M, p) with a planner, ``S_t`` (B, h, p) without (w/o SP)."""
        return history if trace is None else torch.cat([history, trace], dim=1)

    def compute_losses(
        self, batch: dict[str, Tensor], stage: str, generator: torch.Generator | None = None
    ) -> dict[str, Tensor]:
        """Diffusion losses of planner (eq. 3) and generator (eq. 4), summed as in eq. 1.

        Args:
            batch: the ``encode`` keys plus ``observation.state_history`` (B, h, p),
            ``observation.subgoal_trace``
                (B, >=M, p), ``action`` (B, N, A) and optionally ``action_is_pad`` (B, N) bool.
            stage: "stage1" (generator conditioned on the ground-truth trace) or "stage2" (on a planner
                sample, backbone frozen).
            generator: RNG for timesteps, noise, label dropout and the stage-II trace sample.

        Returns:
            ``planner_loss``, ``generator_loss``, with the auxiliary head ``environment_state_loss``
            (weighted; 0 in stage II, where the backbone it trains is frozen), and ``loss`` (their sum);
            planner_loss is 0 without a planner.
        """
        if stage not in ("stage1", "stage2"):
            raise ValueError(f"stage must be 'stage1' or 'stage2', got {stage!r}")
        if stage == "stage2" and self.planner is None:
            raise ValueError("stage2 needs the planner; use_planner=False (w/o SP) trains in stage1 only")
        with torch.set_grad_enabled(torch.is_grad_enabled() and stage == "stage1"):
            hidden, mask = self.encode(batch)  # stage II: backbone frozen, no graph through it
        history = batch[STATE_HISTORY_KEY]
        planner_loss, condition_trace = hidden.new_zeros(()), None
        if self.planner is not None:
            trace = batch[SUBGOAL_TRACE_KEY][:, : self.config.subgoal_trace_len]  # (B, M, p)
            planner_loss, sampled = self._planner_loss(
                hidden, mask, history, trace, stage == "stage2", generator
            )
            condition_trace = trace if sampled is None else sampled
        features, features_mask = self.generator_aggregator(
            self._generator_queries(history, condition_trace), hidden, mask
        )  # (B, h[+M], E)
        is_pad = batch.get(ACTION_IS_PAD_KEY)
        valid = None if is_pad is None else ~is_pad.bool()  # padded actions leave the loss
        generator_loss = self.generator_objective.compute_loss(
            self.generator, batch[ACTION_KEY], features, features_mask, valid, generator
        )
        losses = {"planner_loss": planner_loss, "generator_loss": generator_loss}
        if self.environment_head is not None:
            losses["environment_state_loss"] = (
                self.config.environment_state_weight
                * self.environment_head.loss(hidden, mask, batch[ENV_STATE_KEY])
                if stage == "stage1"
                else hidden.new_zeros(())
            )
        return {**losses, "loss": sum(losses.values())}

    def _planner_loss(
        self,
        hidden: Tensor,
        mask: Tensor,
        history: Tensor,
        trace: Tensor,
        sample_trace: bool,
        generator: torch.Generator | None,
    ) -> tuple[Tensor, Tensor | None]:
        """Planner loss on the ground-truth trace (B, M, p), and in stage II a trace sampled without gradient.

        Returns:
            the scalar loss and the sampled trace (B, M, p), or None when ``sample_trace`` is False.
        """
        features, features_mask = self.planner_aggregator(history, hidden, mask)  # (B, h, E)
        loss = self.planner_objective.compute_loss(
            self.planner, trace, features, features_mask, generator=generator
        )
        if not sample_trace:
            return loss, None
        # The generator must learn to follow the traces it will get at inference, so sample them as inference
        # does: planner and its aggregator in eval mode (no dropout), no gradient.
        with torch.no_grad(), _eval_mode(self.planner_aggregator, self.planner):
            features, features_mask = self.planner_aggregator(history, hidden, mask)
            sampled = self.planner_objective.sample(
                self.planner, tuple(trace.shape), features, features_mask, generator=generator
            )
        return loss, sampled

    @torch.no_grad()
    def plan(
        self, hidden: Tensor, mask: Tensor, history: Tensor, generator: torch.Generator | None = None
    ) -> Tensor:
        """Sample a subgoal trace with the planner (DDIM + CFG).

        Args:
            hidden: (B, S, E) and mask (B, S) from ``encode``; history: (B, h, p) normalised state history.
            generator: RNG for the initial noise.

        Returns:
            (B, M, p) trace in the normalised state space.
        """
        if self.planner is None:
            raise ValueError("plan() needs the planner; this model was built with use_planner=False (w/o SP)")
        features, features_mask = self.planner_aggregator(history, hidden, mask)  # (B, h, E)
        shape = (history.shape[0], self.config.subgoal_trace_len, self.state_dim)
        return self.planner_objective.sample(
            self.planner, shape, features, features_mask, generator=generator
        )

    @torch.no_grad()
    def generate(
        self,
        hidden: Tensor,
        mask: Tensor,
        history: Tensor,
        trace: Tensor | None,
        generator: torch.Generator | None = None,
    ) -> Tensor:
        """Sample an action chunk conditioned on ``[S_t, G]`` (or ``S_t`` alone without a planner).

        Args:
            hidden: (B, S, E) and mask (B, S) from ``encode``; history: (B, h, p); trace: (B, M, p) or None.
            generator: RNG for the initial noise.

        Returns:
            (B, N, A) actions in the normalised action space.
        """
        queries = self._generator_queries(history, trace)
        features, features_mask = self.generator_aggregator(queries, hidden, mask)  # (B, h[+M], E)
        shape = (history.shape[0], self.config.chunk_size, self.action_dim)
        return self.generator_objective.sample(
            self.generator, shape, features, features_mask, generator=generator
        )

    @torch.no_grad()
    def sample_actions(
        self, batch: dict[str, Tensor], generator: torch.Generator | None = None
    ) -> tuple[Tensor, Tensor | None]:
        """Plan a trace and generate an action chunk (one backbone pass, DDIM for both heads).

        Args:
            batch: the ``encode`` keys plus ``observation.state_history`` (B, h, p), normalised.
            generator: RNG for the initial noise of both samplers (None = global RNG).

        Returns:
            actions (B, N, A) and the planned trace (B, M, p) in the normalised space (None without a
            planner).
        """
        hidden, mask = self.encode(batch)
        history = batch[STATE_HISTORY_KEY]
        trace = None if self.planner is None else self.plan(hidden, mask, history, generator)
        return self.generate(hidden, mask, history, trace, generator), trace
