"""The diffusion transformer (DiT) used for BOTH SubgoalVLA heads: the subgoal planner and the action
generator.

Paper appendix B.1/B.2: "The DiT backbone embeds subgoal tokens, timestep features (via an MLP applied to
sinusoidal embeddings), and conditioning inputs, with label dropout (p = 0.1) to enable classifier-free
guidance. Latent variable z is concatenated before the subgoal tokens, and sinusoidal positional embeddings
with a learned global scale are applied. Each block employs pre-LayerNorm self-attention and MLP layers
modulated through AdaLN gates, computed from the timestep embedding combined with pooled z." B.2: "The DiT
backbone and conditioning layers (positional/AdaLN) are identical to those of the subgoal trace planner" - so
one class, instantiated twice.

Interpretation of ``z`` (the paper never defines it further): ``z`` is the conditioning feature sequence
produced by the proprioceptive cross-attention (``f^{c,g}`` for the planner, ``f^{c,a}`` for the generator),
linearly projected to the DiT width. Those projected tokens are (i) concatenated before the noisy input
tokens, so self-attention can read them token by token, and (ii) mean-pooled over their valid positions and
added to the timestep embedding to form the adaLN conditioning vector ``c``. The sinusoidal positions (times a
learned global scale) index the input tokens 0..T-1; ``z`` tokens carry their order from the cross-attention's
per-step query embeddings. Indexing the input tokens from 0 rather than from Tc keeps masked (padded)
conditioning tokens from shifting positions. Label dropout replaces all ``z`` tokens of a sample with one
learned null token, which is what classifier-free guidance evaluates as the "unconditional" branch.

The network is a pure denoiser ``f(x_noisy, t, cond) -> eps_hat``; schedules, losses and sampling live in
``diffusion.py`` (style guide convention 4). Idioms follow facebookresearch/DiT ``models.py``: a ``modulate``
helper, ``TimestepEmbedder``, adaLN-zero blocks, an adaLN ``FinalLayer`` and ``initialize_weights`` zeroing
the modulation so that every block starts as the identity and the output starts at exactly zero.

Dimension legend (the package's, ``__init__.py``): ``B`` batch, ``T`` input tokens (trace steps M or action
steps N), ``X`` input feature size (p or A), ``Tc`` conditioning tokens, ``Dc`` conditioning width, ``D`` DiT
width.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor, nn
from torch.utils.checkpoint import checkpoint


def modulate(x: Tensor, shift: Tensor, scale: Tensor) -> Tensor:
    """adaLN modulation (DiT eq.): ``x * (1 + scale) + shift`` with per-sample ``shift, scale`` (B, D)."""
    return x * (1 + scale.unsqueeze(1)) + shift.unsqueeze(1)


def sinusoidal_embedding(positions: Tensor, dim: int, max_period: float = 10000.0) -> Tensor:
    """Transformer sinusoidal features of (possibly fractional) positions.

    Args:
        positions: (...,) timesteps or token indices.
        dim: output size (odd sizes get one zero column).
        max_period: the longest wavelength.

    Returns:
        (..., dim) ``[cos(pos * w), sin(pos * w)]`` with geometrically spaced frequencies ``w``.
    """
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, device=positions.device) / half)
    args = positions.float().unsqueeze(-1) * freqs  # (..., half)
    emb = torch.cat([torch.cos(args), torch.sin(args)], dim=-1)
    if dim % 2:
        emb = torch.cat([emb, torch.zeros_like(emb[..., :1])], dim=-1)
    return emb


class TimestepEmbedder(nn.Module):
    """Diffusion step -> (B, D): an MLP over sinusoidal features (DiT ``TimestepEmbedder``, appendix B.1)."""

    def __init__(self, hidden_dim: int, frequency_dim: int = 256) -> None:
        super().__init__()
        self.frequency_dim = frequency_dim
        self.mlp = nn.Sequential(
            nn.Linear(frequency_dim, hidden_dim), nn.SiLU(), nn.Linear(hidden_dim, hidden_dim)
        )

    def forward(self, timesteps: Tensor) -> Tensor:
        """Args: timesteps (B,) integer or float steps. Returns: (B, D)."""
        return self.mlp(sinusoidal_embedding(timesteps, self.frequency_dim))


class DiTBlock(nn.Module):
    """Pre-LN self-attention + MLP block with adaLN-zero modulation (shift/scale/gate for both sub-layers)."""

    def __init__(self, hidden_dim: int, num_heads: int, mlp_ratio: float) -> None:
        super().__init__()
        self.norm1 = nn.LayerNorm(hidden_dim, elementwise_affine=False, eps=1e-6)
        self.attn = nn.MultiheadAttention(hidden_dim, num_heads, batch_first=True)
        self.norm2 = nn.LayerNorm(hidden_dim, elementwise_affine=False, eps=1e-6)
        mlp_dim = int(hidden_dim * mlp_ratio)
        self.mlp = nn.Sequential(
            nn.Linear(hidden_dim, mlp_dim),
            nn.GELU(approximate="tanh"),
            nn.Linear(mlp_dim, hidden_dim),
        )
        self.adaLN_modulation = nn.Sequential(nn.SiLU(), nn.Linear(hidden_dim, 6 * hidden_dim))  # noqa: N815

    def _load_from_state_dict(self, state_dict: dict[str, Tensor], prefix: str, *args: Any) -> None:
        # Checkpoints saved before the MLP lost its dropout layer (always p = 0: the same function) keep
        # the output projection at index 3; without the rename it would load as missing and stay random.
        for name in ("weight", "bias"):
            old, new = f"{prefix}mlp.3.{name}", f"{prefix}mlp.2.{name}"
            if old in state_dict and new not in state_dict:
                state_dict[new] = state_dict.pop(old)
        super()._load_from_state_dict(state_dict, prefix, *args)

    def forward(self, x: Tensor, c: Tensor, key_padding_mask: Tensor | None) -> Tensor:
        """Args: x (B, Tc+T, D); c (B, D); key_padding_mask (B, Tc+T) True = ignore. Returns (B, Tc+T, D)."""
        shift_msa, scale_msa, gate_msa, shift_mlp, scale_mlp, gate_mlp = self.adaLN_modulation(c).chunk(
            6, dim=-1
        )
        h = modulate(self.norm1(x), shift_msa, scale_msa)
        attn_out = self.attn(h, h, h, key_padding_mask=key_padding_mask, need_weights=False)[0]
        x = x + gate_msa.unsqueeze(1) * attn_out
        return x + gate_mlp.unsqueeze(1) * self.mlp(modulate(self.norm2(x), shift_mlp, scale_mlp))


class FinalLayer(nn.Module):
    """adaLN-modulated LayerNorm + Linear back to the input feature size (DiT ``FinalLayer``)."""

    def __init__(self, hidden_dim: int, out_dim: int) -> None:
        super().__init__()
        self.norm_final = nn.LayerNorm(hidden_dim, elementwise_affine=False, eps=1e-6)
        self.linear = nn.Linear(hidden_dim, out_dim)
        self.adaLN_modulation = nn.Sequential(nn.SiLU(), nn.Linear(hidden_dim, 2 * hidden_dim))  # noqa: N815

    def forward(self, x: Tensor, c: Tensor) -> Tensor:
        """Args: x (B, T, D); c (B, D). Returns (B, T, out_dim)."""
        shift, scale = self.adaLN_modulation(c).chunk(2, dim=-1)
        return self.linear(modulate(self.norm_final(x), shift, scale))


class DiT(nn.Module):
    """Conditional DiT denoiser shared by the planner (x = trace G, X = p) and the generator (x = actions, X =
    A).

    Args:
        input_dim: X, feature size of each noisy token (proprio dim p for the planner, action dim A).
        cond_dim: Dc, width of the conditioning features from the cross-attention.
        hidden_dim: D, transformer width (768 for DiT-B).
        depth: number of DiT blocks (12 for DiT-B).
        num_heads: attention heads (paper table 5: 12; section 5.1 says 8 - see docs/model.md).
        mlp_ratio: MLP expansion of each block.

    No dropout inside the blocks, as in DiT and CogACT's action head: the only regulariser is label dropout
    (``drop_cond``), which classifier-free guidance needs.

    ``gradient_checkpointing`` (set by ``SubgoalVLAConfig.gradient_checkpointing``): in training, each block
    keeps only its input and recomputes its activations during the backward pass (``docs/memory.md``).
    """

    def __init__(
        self,
        input_dim: int,
        cond_dim: int,
        hidden_dim: int,
        depth: int,
        num_heads: int,
        mlp_ratio: float = 4.0,
    ) -> None:
        super().__init__()
        if hidden_dim % num_heads:
            raise ValueError(f"DiT hidden_dim={hidden_dim} must be divisible by num_heads={num_heads}")
        self.hidden_dim = hidden_dim
        self.x_embedder = nn.Linear(input_dim, hidden_dim)
        self.t_embedder = TimestepEmbedder(hidden_dim)
        self.z_embedder = nn.Linear(cond_dim, hidden_dim)  # z = projected conditioning features
        self.null_z = nn.Parameter(torch.zeros(hidden_dim))  # label-dropout token for CFG
        self.z_pool_proj = nn.Linear(hidden_dim, hidden_dim)  # pooled z -> adaLN conditioning
        # learned global scale of the sinusoidal positions; shape (1,), not (): FSDP refuses 0-d parameters
        self.pos_scale = nn.Parameter(torch.ones(1))
        self.blocks = nn.ModuleList(DiTBlock(hidden_dim, num_heads, mlp_ratio) for _ in range(depth))
        self.final_layer = FinalLayer(hidden_dim, input_dim)
        self.gradient_checkpointing = False
        self.initialize_weights()

    def _load_from_state_dict(self, state_dict: dict[str, Tensor], prefix: str, *args: Any) -> None:
        # Checkpoints saved before the sharded-training support hold pos_scale as a 0-d tensor.
        key = f"{prefix}pos_scale"
        if key in state_dict and state_dict[key].ndim == 0:
            state_dict[key] = state_dict[key].reshape(1)
        super()._load_from_state_dict(state_dict, prefix, *args)

    def initialize_weights(self) -> None:
        """DiT initialisation: Xavier linears, N(0, 0.02) embedders, adaLN-zero.

        Zeroing every adaLN modulation makes each block the identity at initialisation (gates = 0), and
        zeroing the final layer makes the initial noise prediction exactly 0, which is what "adaLN-zero"
        refers to.
        """

        def _basic_init(module: nn.Module) -> None:
            if isinstance(module, nn.Linear):
                nn.init.xavier_uniform_(module.weight)
                if module.bias is not None:
                    nn.init.zeros_(module.bias)

        self.apply(_basic_init)
        nn.init.normal_(self.t_embedder.mlp[0].weight, std=0.02)
        nn.init.normal_(self.t_embedder.mlp[2].weight, std=0.02)
        nn.init.normal_(self.null_z, std=0.02)
        for block in self.blocks:
            nn.init.zeros_(block.adaLN_modulation[-1].weight)
            nn.init.zeros_(block.adaLN_modulation[-1].bias)
        nn.init.zeros_(self.final_layer.adaLN_modulation[-1].weight)
        nn.init.zeros_(self.final_layer.adaLN_modulation[-1].bias)
        nn.init.zeros_(self.final_layer.linear.weight)
        nn.init.zeros_(self.final_layer.linear.bias)

    def embed_condition(
        self, cond: Tensor, cond_mask: Tensor | None, drop_cond: Tensor | None
    ) -> tuple[Tensor, Tensor, Tensor | None]:
        """Project the conditioning features to z tokens, apply label dropout, pool them.

        Args:
            cond: (B, Tc, Dc) cross-attention features.
            cond_mask: (B, Tc) bool, True = valid; None = all valid.
            drop_cond: (B,) bool, True = replace this sample's condition by the learned null token.

        Returns:
            z: (B, Tc, D) tokens placed before the input tokens; pooled: (B, D) masked mean of z;
            valid: (B, Tc) bool, which z tokens self-attention may read (None = all).
        """
        z = self.z_embedder(cond)  # (B, Tc, D)
        if drop_cond is not None:
            z = torch.where(drop_cond[:, None, None], self.null_z.to(z.dtype).expand_as(z), z)
        if cond_mask is None:  # no mask: plain mean, and attention keeps its fast path
            return z, z.mean(dim=1), None
        valid = cond_mask if drop_cond is None else cond_mask | drop_cond[:, None]  # null token fully visible
        weights = valid.to(z.dtype).unsqueeze(-1)  # (B, Tc, 1)
        pooled = (z * weights).sum(dim=1) / weights.sum(dim=1).clamp_min(1.0)  # (B, D)
        return z, pooled, valid

    def forward(
        self,
        x_noisy: Tensor,
        timesteps: Tensor,
        cond: Tensor,
        cond_mask: Tensor | None = None,
        drop_cond: Tensor | None = None,
    ) -> Tensor:
        """Predict the noise in ``x_noisy``.

        Args:
            x_noisy: (B, T, X) noisy trace or action chunk.
            timesteps: (B,) diffusion step indices.
            cond: (B, Tc, Dc) conditioning features.
            cond_mask: (B, Tc) bool, True = valid conditioning token; None = all valid.
            drop_cond: (B,) bool label-dropout mask (True = unconditional); None = keep all.

        Returns:
            (B, T, X) predicted noise.
        """
        num_x = x_noisy.shape[1]
        z, pooled, z_valid = self.embed_condition(cond, cond_mask, drop_cond)
        c = self.t_embedder(timesteps).to(z.dtype) + self.z_pool_proj(pooled)  # (B, D)
        x = self.x_embedder(x_noisy)  # (B, T, D)
        positions = torch.arange(num_x, device=x.device)
        x = x + self.pos_scale * sinusoidal_embedding(positions, self.hidden_dim).to(x.dtype)
        tokens = torch.cat([z, x], dim=1)  # (B, Tc+T, D): z before the input tokens
        key_padding_mask = None  # (B, Tc+T) True = ignore; input tokens are always visible
        if z_valid is not None:
            x_valid = torch.ones(x.shape[:2], dtype=torch.bool, device=x.device)
            key_padding_mask = ~torch.cat([z_valid, x_valid], dim=1)
        checkpointed = self.gradient_checkpointing and self.training and torch.is_grad_enabled()
        for block in self.blocks:
            if checkpointed:
                tokens = checkpoint(block, tokens, c, key_padding_mask, use_reentrant=False)
            else:
                tokens = block(tokens, c, key_padding_mask)
        return self.final_layer(tokens[:, -num_x:], c)  # (B, T, X)


def count_parameters(module: nn.Module) -> int:
    """Number of parameters of ``module`` (works on the meta device)."""
    return sum(p.numel() for p in module.parameters())


__all__ = ["DiT", "DiTBlock", "FinalLayer", "TimestepEmbedder", "count_parameters", "modulate"]
