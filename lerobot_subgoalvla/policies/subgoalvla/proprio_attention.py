"""Proprioceptive cross-attention (PCA, paper eq. 2) and the table-4 feature aggregation ablations.

PCA lets the robot's proprioception choose which vision-language tokens matter (section 4.1): queries come
from a Linear projection of the state history S_t (planner) or of ``[S_t, G]`` (generator); keys/values are
the layer-k hidden states H[k] of the VLM. Eq. 2 with the pre-normalisation and dropout the paper omits "for
clarity":

    f = Dropout(MHA(LN_q(Q), LN_kv(H), LN_kv(H))) + Q
    f = Dropout(MLP(LN(f))) + f
    features = LN_out(f)            after the last block

The final ``LN_out`` is ours too: with pre-normalisation the residual stream is never normalised, and the DiT
takes these features as conditioning tokens next to its own normalised inputs, so they leave at unit scale
(as a pre-LN transformer encoder ends with a LayerNorm).

Vocabulary (style guide convention 6): ``hidden_states`` are the query tokens, ``encoder_hidden_states`` the
VLM tokens and ``encoder_attention_mask`` their padding mask (True = valid), which reaches the attention op as
``key_padding_mask`` so padded VLM tokens never influence the output. No self-attention between queries: each
block is cross-attention then MLP (the paper's figure 4 shows only cross-attention).

Ablations (paper table 4, appendix D.1) share one interface, ``aggregator(proprio, H, mask) -> (features,
features_mask | None)`` (None = all features valid), so the model swaps them by name
(``feature_aggregation``):

- ``mean``: the k tokens most similar (dot product) to the masked mean token;
- ``max``: the k tokens with the largest L2 norm;
- ``attn``: scores ``a_i = alpha * H_i . q`` with a learned query q and scale alpha; top-k by score, and the
  selected tokens are re-weighted by ``k * softmax(a_topk)`` so q and alpha receive gradients (top-k alone is
  not differentiable; with equal scores the weights are 1).

Pooling removes the proprioceptive conditioning of the feature *selection*, which is what table 4 ablates; the
proprioceptive tokens themselves (Linear(S_t) or Linear([S_t, G])) are still handed to the DiT next to the
selected tokens, so the ablated heads see the same information except for the state-aware selection. Selected
tokens pass through LayerNorm + Linear to the feature width (mid-layer LLM states have large, uneven norms).

Dimension legend (the package's, ``__init__.py``): ``B`` batch, ``Q`` query tokens (h or h+M), ``p`` proprio
dim, ``S`` VLM tokens, ``E`` VLM width, ``D`` feature width, ``K`` selected tokens.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Literal

import torch
from torch import Tensor, nn
from torch.utils.checkpoint import checkpoint

if TYPE_CHECKING:
    from lerobot_subgoalvla.policies.subgoalvla.config_components import CrossAttentionConfig

AggregationName = Literal["proprio_xattn", "mean", "max", "attn"]


class ProprioCrossAttentionBlock(nn.Module):
    """One eq.-2 block: pre-norm multi-head cross-attention with residual, then pre-norm MLP with residual.

    Args:
        dim: D, query / output width.
        encoder_dim: E, width of the VLM tokens (keys and values).
        num_heads: attention heads (8 in the paper).
        mlp_ratio: hidden size of the MLP relative to ``dim``.
        dropout: dropout on attention weights and after both sub-layers.
    """

    def __init__(self, dim: int, encoder_dim: int, num_heads: int, mlp_ratio: float, dropout: float) -> None:
        super().__init__()
        if dim % num_heads:
            raise ValueError(f"cross-attention dim={dim} must be divisible by num_heads={num_heads}")
        self.norm_q = nn.LayerNorm(dim)
        self.norm_kv = nn.LayerNorm(encoder_dim)
        self.attn = nn.MultiheadAttention(
            dim, num_heads, dropout=dropout, batch_first=True, kdim=encoder_dim, vdim=encoder_dim
        )
        self.norm_mlp = nn.LayerNorm(dim)
        hidden = int(dim * mlp_ratio)
        self.mlp = nn.Sequential(
            nn.Linear(dim, hidden), nn.GELU(), nn.Dropout(dropout), nn.Linear(hidden, dim)
        )
        self.dropout = nn.Dropout(dropout)

    def forward(
        self, hidden_states: Tensor, encoder_hidden_states: Tensor, encoder_attention_mask: Tensor | None
    ) -> Tensor:
        """Args: hidden_states (B, Q, D); encoder_hidden_states (B, S, E); encoder_attention_mask (B, S)
        True=valid.

        Returns:
            (B, Q, D) updated query features.
        """
        kv = self.norm_kv(encoder_hidden_states)
        padding = None if encoder_attention_mask is None else ~encoder_attention_mask.bool()
        attn = self.attn(self.norm_q(hidden_states), kv, kv, key_padding_mask=padding, need_weights=False)[0]
        hidden_states = hidden_states + self.dropout(attn)
        return hidden_states + self.dropout(self.mlp(self.norm_mlp(hidden_states)))


class ProprioQueryEmbedding(nn.Module):
    """``Q_proprio = Linear(S_t)`` (or ``Linear([S_t, G])``) plus a learned per-step embedding.

    The paper writes only the Linear; the per-step embedding is our addition so that the order of the history
    and trace steps (and which tokens are trace) survives attention, which is permutation-equivariant over
    queries.
    """

    def __init__(self, proprio_dim: int, num_queries: int, dim: int) -> None:
        super().__init__()
        self.proj = nn.Linear(proprio_dim, dim)
        self.step_embedding = nn.Parameter(torch.zeros(num_queries, dim))
        nn.init.normal_(self.step_embedding, std=0.02)

    def forward(self, proprio: Tensor) -> Tensor:
        """Args: proprio (B, Q, p). Returns (B, Q, D)."""
        if proprio.shape[1] != self.step_embedding.shape[0]:
            raise ValueError(
                f"expected {self.step_embedding.shape[0]} proprio steps (history [+ trace]), got "
                f"{proprio.shape[1]}"
            )
        return self.proj(proprio) + self.step_embedding


class ProprioCrossAttention(nn.Module):
    """The PCA module: proprio query embedding followed by ``num_layers`` eq.-2 blocks (3 layers, 8 heads).

    Args:
        proprio_dim: p, size of one proprio step.
        num_queries: Q, number of proprio steps (h for the planner, h + M for the generator).
        encoder_dim: E, VLM hidden size.
        dim: D, feature width (the paper uses the VLM width, 4096 for LLaMA-7B).
        num_layers: number of blocks.
        num_heads: attention heads.
        mlp_ratio: MLP expansion.
        dropout: dropout probability.

    ``gradient_checkpointing`` (set by ``SubgoalVLAConfig.gradient_checkpointing``): in training, each block
    keeps only its inputs and recomputes its activations (its keys and values over the S VLM tokens are the
    large part) during the backward pass; dropout draws the same masks again (``docs/memory.md``).
    """

    def __init__(
        self,
        proprio_dim: int,
        num_queries: int,
        encoder_dim: int,
        dim: int,
        num_layers: int = 3,
        num_heads: int = 8,
        mlp_ratio: float = 4.0,
        dropout: float = 0.1,
    ) -> None:
        super().__init__()
        self.queries = ProprioQueryEmbedding(proprio_dim, num_queries, dim)
        self.blocks = nn.ModuleList(
            ProprioCrossAttentionBlock(dim, encoder_dim, num_heads, mlp_ratio, dropout)
            for _ in range(num_layers)
        )
        self.norm_out = nn.LayerNorm(dim)  # LN_out of the module docstring
        self.gradient_checkpointing = False

    def forward(
        self, proprio: Tensor, encoder_hidden_states: Tensor, encoder_attention_mask: Tensor | None
    ) -> tuple[Tensor, None]:
        """Args: proprio (B, Q, p); encoder_hidden_states (B, S, E); encoder_attention_mask (B, S) True=valid.

        Returns:
            features (B, Q, D) and their mask: None, every query token is a valid feature.
        """
        hidden_states = self.queries(proprio)  # (B, Q, D)
        checkpointed = self.gradient_checkpointing and self.training and torch.is_grad_enabled()
        for block in self.blocks:
            args = (hidden_states, encoder_hidden_states, encoder_attention_mask)
            hidden_states = checkpoint(block, *args, use_reentrant=False) if checkpointed else block(*args)
        return self.norm_out(hidden_states), None


class TopKTokenPooling(nn.Module):
    """Table-4 baselines: select K VLM tokens by a state-independent score (appendix D.1).

    Args:
        method: "mean" (similarity to the masked mean), "max" (L2 norm) or "attn" (learned query q, scale
        alpha). proprio_dim, num_queries: as in ``ProprioCrossAttention`` (the proprio tokens are passed
        through).
        encoder_dim: E, VLM hidden size.
        dim: D, feature width.
        top_k: K, tokens kept (clamped to the sequence length).
    """

    def __init__(
        self,
        method: Literal["mean", "max", "attn"],
        proprio_dim: int,
        num_queries: int,
        encoder_dim: int,
        dim: int,
        top_k: int,
    ) -> None:
        super().__init__()
        if method not in ("mean", "max", "attn"):
            raise ValueError(f"pooling method must be one of mean, max, attn; got {method!r}")
        self.method = method
        self.top_k = top_k
        self.queries = ProprioQueryEmbedding(proprio_dim, num_queries, dim)
        self.token_proj = nn.Sequential(nn.LayerNorm(encoder_dim), nn.Linear(encoder_dim, dim))
        if method == "attn":
            self.score_query = nn.Parameter(torch.randn(encoder_dim) / encoder_dim**0.5)
            # shape (1,), not (): FSDP refuses 0-d parameters
            self.score_scale = nn.Parameter(torch.full((1,), 1.0 / encoder_dim**0.5))

    def _load_from_state_dict(self, state_dict: dict[str, Tensor], prefix: str, *args: Any) -> None:
        # Checkpoints saved before the sharded-training support hold score_scale as a 0-d tensor.
        key = f"{prefix}score_scale"
        if key in state_dict and state_dict[key].ndim == 0:
            state_dict[key] = state_dict[key].reshape(1)
        super()._load_from_state_dict(state_dict, prefix, *args)

    def token_scores(self, encoder_hidden_states: Tensor, valid: Tensor) -> Tensor:
        """Args: encoder_hidden_states (B, S, E); valid (B, S) bool. Returns (B, S) scores, -inf on
        padding."""
        h = encoder_hidden_states.float()
        if self.method == "mean":
            w = valid.unsqueeze(-1).float()
            mean = (h * w).sum(dim=1) / w.sum(dim=1).clamp_min(1.0)  # (B, E)
            scores = torch.einsum("bse,be->bs", h, mean)
        elif self.method == "max":
            scores = h.norm(dim=-1)
        else:
            scores = self.score_scale * torch.einsum("bse,e->bs", h, self.score_query.float())
        return scores.masked_fill(~valid, float("-inf"))

    def forward(
        self, proprio: Tensor, encoder_hidden_states: Tensor, encoder_attention_mask: Tensor | None
    ) -> tuple[Tensor, Tensor]:
        """Args: proprio (B, Q, p); encoder_hidden_states (B, S, E); encoder_attention_mask (B, S) True=valid.

        Returns:
            features (B, Q + K, D): proprio tokens then the selected VLM tokens; mask (B, Q + K), False where
            a sequence has fewer than K valid tokens.
        """
        b, s, _ = encoder_hidden_states.shape
        valid = torch.ones(b, s, dtype=torch.bool, device=encoder_hidden_states.device)
        if encoder_attention_mask is not None:
            valid = encoder_attention_mask.bool()
        k = min(self.top_k, s)
        scores, index = self.token_scores(encoder_hidden_states, valid).topk(k, dim=-1)  # (B, K)
        selected = torch.gather(
            encoder_hidden_states, 1, index.unsqueeze(-1).expand(-1, -1, encoder_hidden_states.shape[-1])
        )  # (B, K, E)
        selected = self.token_proj(selected)  # (B, K, D)
        selected_valid = torch.isfinite(scores)
        if self.method == "attn":
            weights = k * torch.softmax(scores.masked_fill(~selected_valid, float("-inf")), dim=-1)
            selected = selected * weights.nan_to_num(0.0).unsqueeze(-1).to(selected.dtype)
        tokens = self.queries(proprio)  # (B, Q, D)
        mask = torch.cat(
            [torch.ones(tokens.shape[:2], dtype=torch.bool, device=tokens.device), selected_valid], 1
        )
        return torch.cat([tokens, selected], dim=1), mask


def build_aggregator(
    name: AggregationName,
    *,
    proprio_dim: int,
    num_queries: int,
    encoder_dim: int,
    dim: int,
    attention: CrossAttentionConfig,
    top_k: int,
) -> nn.Module:
    """The feature aggregator named by ``feature_aggregation`` (proprio_xattn | mean | max | attn).

    ``attention`` configures the cross-attention (layers, heads, MLP ratio, dropout); ``top_k`` the pooling
    baselines.
    """
    if name == "proprio_xattn":
        return ProprioCrossAttention(
            proprio_dim,
            num_queries,
            encoder_dim,
            dim,
            num_layers=attention.num_layers,
            num_heads=attention.num_heads,
            mlp_ratio=attention.mlp_ratio,
            dropout=attention.dropout,
        )
    if name in ("mean", "max", "attn"):
        return TopKTokenPooling(name, proprio_dim, num_queries, encoder_dim, dim, top_k)
    raise ValueError(f"feature_aggregation must be one of proprio_xattn, mean, max, attn; got {name!r}")
