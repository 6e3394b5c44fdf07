"""An auxiliary training head: the dataset's environment state read back from the vision-language features.

Not part of the paper. A vision tower learned from scratch sees only what the action loss asks of it, and a
small share of that loss depends on fine object detail: on CALVIN's play data the trained encoding holds the
blocks' yaw no better than an untrained copy of the model (a linear probe, docs/RESULTS.md), although every
grasp turns the hand to it. Datasets that record ``observation.environment_state`` (CALVIN's scene_obs: the
doors, switches and block poses) give a direct target: this head regresses it from the layer-k states, and its
loss trains the backbone to carry what the scene holds. The head is used in training only (stage I, where the
backbone learns); at inference nothing reads it and the env need not provide the feature. Off by default: at
weight 0.1 it made the CALVIN policy's chains shorter (docs/RESULTS.md): an option to study, in no recipe.

The target is z-scored with the dataset's statistics, stored in the head (saved with the weights), so that
every dimension weighs alike whatever its unit.

Dimension legend: ``B`` batch, ``S`` tokens, ``E`` hidden width, ``Q`` queries, ``D`` environment-state dims.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from einops import rearrange
from torch import Tensor, nn

from lerobot_subgoalvla.config_error import DatasetContractError
from lerobot_subgoalvla.contract.keys import ENV_STATE_KEY

#: Learned queries that pool the tokens: a few, so that several objects can be attended at once.
NUM_QUERIES = 4


class EnvironmentStateHead(nn.Module):
    """Learned queries attend over the vision-language tokens; a linear map reads the environment state.

    Args:
        width: E, the backbone's hidden width.
        num_heads: attention heads (E must be divisible by it).
        state_dim: D, the size of ``observation.environment_state``.
    """

    def __init__(self, width: int, num_heads: int, state_dim: int) -> None:
        super().__init__()
        self.queries = nn.Parameter(torch.randn(NUM_QUERIES, width) * 0.02)  # (Q, E)
        self.norm = nn.LayerNorm(width)
        self.attention = nn.MultiheadAttention(width, num_heads, batch_first=True)
        self.readout = nn.Linear(NUM_QUERIES * width, state_dim)
        # The dataset's statistics of the target (set once from the training dataset, saved with the weights).
        self.register_buffer("target_mean", torch.zeros(state_dim))
        self.register_buffer("target_std", torch.ones(state_dim))

    def set_statistics(self, dataset_stats: Mapping[str, Mapping[str, object]] | None) -> None:
        """Take the target's mean and std from the training dataset's statistics (``meta.stats``)."""
        stats = (dataset_stats or {}).get(ENV_STATE_KEY) or {}
        if "mean" not in stats or "std" not in stats:
            raise DatasetContractError(
                f"--policy.environment_state_weight needs the dataset's mean and std of {ENV_STATE_KEY!r}, "
                "which its meta/stats.json lacks; recompute the statistics or set the weight to 0"
            )
        mean = torch.as_tensor(stats["mean"], dtype=torch.float32).flatten()
        std = torch.as_tensor(stats["std"], dtype=torch.float32).flatten()
        if mean.shape != self.target_mean.shape or std.shape != self.target_std.shape:
            raise DatasetContractError(
                f"the dataset's statistics of {ENV_STATE_KEY!r} have shape {tuple(mean.shape)}, the feature "
                f"{tuple(self.target_mean.shape)}; recompute the statistics (meta/stats.json)"
            )
        self.target_mean.copy_(mean)
        # A constant dimension (Meta-World's unused object slots) keeps unit scale: its centred target is 0,
        # and float noise around the mean is not blown up by a near-zero std.
        self.target_std.copy_(torch.where(std > 1e-6, std, torch.ones_like(std)))

    def forward(self, hidden: Tensor, mask: Tensor) -> Tensor:
        """Predicted z-scored environment state (B, D) from hidden (B, S, E) and mask (B, S), True = valid."""
        queries = self.queries.expand(len(hidden), -1, -1)  # (B, Q, E)
        tokens = self.norm(hidden)  # (B, S, E)
        pooled, _ = self.attention(queries, tokens, tokens, key_padding_mask=~mask)  # (B, Q, E)
        return self.readout(rearrange(pooled, "b q e -> b (q e)"))

    def loss(self, hidden: Tensor, mask: Tensor, environment_state: Tensor) -> Tensor:
        """Mean squared error of the z-scored prediction; ``environment_state`` (B, D) in dataset units."""
        target = (environment_state.float() - self.target_mean) / self.target_std
        return nn.functional.mse_loss(self.forward(hidden, mask), target)
