"""Proprioceptive cross-attention (eq. 2) and the table-4 pooling aggregators: shapes, masks, gradients."""

from __future__ import annotations

import pytest
import torch

from lerobot_subgoalvla.policies.subgoalvla.config_components import CrossAttentionConfig
from lerobot_subgoalvla.policies.subgoalvla.proprio_attention import (
    ProprioCrossAttention,
    ProprioCrossAttentionBlock,
    TopKTokenPooling,
    build_aggregator,
)

B, Q, P, S, E, D = 2, 6, 15, 10, 24, 16
SIZES = {"proprio_dim": P, "num_queries": Q, "encoder_dim": E, "dim": D}
ATTENTION = CrossAttentionConfig(num_layers=2, num_heads=4, mlp_ratio=2.0, dropout=0.0)


def _append_padding(hidden: torch.Tensor, mask: torch.Tensor, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    pad = 50 * torch.randn(hidden.shape[0], n, hidden.shape[-1])
    return torch.cat([hidden, pad], dim=1), torch.cat(
        [mask, torch.zeros(mask.shape[0], n, dtype=torch.bool)], 1
    )


def test_block_residual_structure_and_shapes() -> None:
    block = ProprioCrossAttentionBlock(D, E, num_heads=4, mlp_ratio=2.0, dropout=0.0)
    queries, tokens = torch.randn(B, Q, D), torch.randn(B, S, E)
    out = block(queries, tokens, torch.ones(B, S, dtype=torch.bool))
    assert out.shape == (B, Q, D)
    with torch.no_grad():  # zero both sub-layer outputs: the dual residual must return the queries unchanged
        block.attn.out_proj.weight.zero_()
        block.attn.out_proj.bias.zero_()
        block.mlp[-1].weight.zero_()
        block.mlp[-1].bias.zero_()
    torch.testing.assert_close(block(queries, tokens, None), queries)


@pytest.mark.parametrize("name", ["proprio_xattn", "mean", "max", "attn"])
def test_padding_tokens_do_not_change_the_features(name: str) -> None:
    module = build_aggregator(name, **SIZES, attention=ATTENTION, top_k=4)
    module.eval()
    proprio, hidden = torch.randn(B, Q, P), torch.randn(B, S, E)
    mask = torch.ones(B, S, dtype=torch.bool)
    mask[1, 7:] = False  # sample 1 already has some padding
    features, features_mask = module(proprio, hidden, mask)
    padded_hidden, padded_mask = _append_padding(hidden, mask, 5)
    padded_features, padded_features_mask = module(proprio, padded_hidden, padded_mask)
    torch.testing.assert_close(padded_features, features, atol=1e-5, rtol=1e-5)
    assert (features_mask is None and padded_features_mask is None) or torch.equal(
        padded_features_mask, features_mask
    )


def test_cross_attention_depends_on_proprio_and_tokens() -> None:
    module = ProprioCrossAttention(P, Q, E, D, num_layers=3, num_heads=4, mlp_ratio=4.0, dropout=0.0)
    proprio, hidden = torch.randn(B, Q, P), torch.randn(B, S, E)
    features, mask = module(proprio, hidden, None)
    assert features.shape == (B, Q, D) and mask is None  # every query token is a valid feature
    assert not torch.allclose(features, module(proprio + 1.0, hidden, None)[0])
    assert not torch.allclose(features, module(proprio, torch.randn(B, S, E), None)[0])
    with pytest.raises(ValueError, match="expected 6 proprio steps"):
        module(torch.randn(B, Q + 1, P), hidden, None)


def test_pooling_selects_tokens_by_the_documented_scores() -> None:
    hidden = torch.zeros(1, 5, E)
    hidden[0, 3] = 10.0  # largest norm
    hidden[0, 1] = 3.0
    valid = torch.ones(1, 5, dtype=torch.bool)
    max_pool = TopKTokenPooling("max", P, Q, E, D, top_k=2)
    assert max_pool.token_scores(hidden, valid).topk(2).indices.tolist() == [[3, 1]]
    mean_pool = TopKTokenPooling("mean", P, Q, E, D, top_k=1)
    hidden_mean = torch.randn(1, 5, E)
    mean = hidden_mean.mean(dim=1)
    expected = (hidden_mean[0] @ mean[0]).argmax()
    assert mean_pool.token_scores(hidden_mean, valid).argmax() == expected
    masked = valid.clone()
    masked[0, 3] = False
    assert max_pool.token_scores(hidden, masked).topk(1).indices.item() == 1  # padding never selected


def test_attention_pooling_learns_its_query_and_scale() -> None:
    module = TopKTokenPooling("attn", P, Q, E, D, top_k=3)
    features, mask = module(torch.randn(B, Q, P), torch.randn(B, S, E), torch.ones(B, S, dtype=torch.bool))
    assert features.shape == (B, Q + 3, D) and mask.all()
    features.pow(2).mean().backward()
    assert module.score_query.grad.abs().sum() > 0 and module.score_scale.grad.abs() > 0


def test_short_sequences_mark_missing_selections_invalid() -> None:
    module = TopKTokenPooling("max", P, Q, E, D, top_k=4)
    mask = torch.zeros(1, S, dtype=torch.bool)
    mask[0, :2] = True
    _, features_mask = module(torch.randn(1, Q, P), torch.randn(1, S, E), mask)
    assert features_mask[0, :Q].all() and features_mask[0, Q:].tolist() == [True, True, False, False]


def test_unknown_aggregation_is_rejected() -> None:
    with pytest.raises(ValueError, match="proprio_xattn, mean, max, attn"):
        build_aggregator("median", **SIZES, attention=ATTENTION, top_k=4)


def test_attention_pooling_scale_has_a_dimension_and_old_scalar_checkpoints_load() -> None:
    """FSDP refuses 0-d parameters; checkpoints saved when score_scale was 0-d still load (reshaped)."""
    module = TopKTokenPooling("attn", P, Q, E, D, top_k=3)
    assert all(p.dim() >= 1 for p in module.parameters())
    state = module.state_dict()
    state["score_scale"] = torch.tensor(0.25)
    module.load_state_dict(state)
    assert module.score_scale.shape == (1,) and module.score_scale.item() == 0.25
