"""DiT: shapes, adaLN-zero initialisation, conditioning masks, label dropout, one class for both heads."""

from __future__ import annotations

import torch

from lerobot_subgoalvla.policies.subgoalvla.dit import DiT, count_parameters


def _dit(input_dim: int = 15, cond_dim: int = 24) -> DiT:
    return DiT(input_dim=input_dim, cond_dim=cond_dim, hidden_dim=32, depth=2, num_heads=4)


def _perturb(model: DiT) -> None:
    """Leave adaLN-zero: random weights everywhere so outputs depend on every input."""
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.1 * torch.randn_like(p))


def test_output_shape_and_adaln_zero_init_gives_zero_prediction() -> None:
    model = _dit()
    x = torch.randn(3, 8, 15)
    out = model(x, torch.tensor([0, 3, 7]), torch.randn(3, 5, 24))
    assert out.shape == (3, 8, 15)
    assert torch.count_nonzero(out) == 0  # FinalLayer linear + modulation zero-initialised
    for block in model.blocks:
        assert torch.count_nonzero(block.adaLN_modulation[-1].weight) == 0


def test_one_class_serves_planner_and_generator() -> None:
    planner, generator = _dit(input_dim=15), _dit(input_dim=7)
    _perturb(planner)
    _perturb(generator)
    cond = torch.randn(2, 15, 24)
    assert planner(torch.randn(2, 8, 15), torch.tensor([1, 2]), cond).shape == (2, 8, 15)
    assert generator(torch.randn(2, 15, 7), torch.tensor([1, 2]), cond).shape == (2, 15, 7)
    assert type(planner) is type(generator)


def test_prediction_depends_on_timestep_and_condition() -> None:
    model = _dit()
    _perturb(model)
    x, cond = torch.randn(1, 8, 15), torch.randn(1, 5, 24)
    base = model(x, torch.tensor([2]), cond)
    assert not torch.allclose(base, model(x, torch.tensor([5]), cond))
    assert not torch.allclose(base, model(x, torch.tensor([2]), torch.randn(1, 5, 24)))


def test_masked_condition_tokens_are_ignored() -> None:
    model = _dit().eval()
    _perturb(model)
    x, cond = torch.randn(1, 8, 15), torch.randn(1, 5, 24)
    padded = torch.cat([cond, 100 * torch.randn(1, 3, 24)], dim=1)
    mask = torch.tensor([[True] * 5 + [False] * 3])
    torch.testing.assert_close(model(x, torch.tensor([4]), cond), model(x, torch.tensor([4]), padded, mask))


def test_label_dropout_replaces_condition_with_null_token() -> None:
    model = _dit().eval()
    _perturb(model)
    x = torch.randn(2, 8, 15)
    t = torch.tensor([3, 3])
    drop = torch.tensor([True, True])
    a = model(x, t, torch.randn(2, 5, 24), drop_cond=drop)
    b = model(x, t, torch.randn(2, 5, 24), drop_cond=drop)
    torch.testing.assert_close(a, b)  # unconditional: the condition's values no longer matter
    kept = model(x, t, torch.randn(2, 5, 24), drop_cond=torch.tensor([False, True]))
    torch.testing.assert_close(kept[1], a[1])
    assert not torch.allclose(kept[0], a[0])


def test_dit_b_parameter_count() -> None:
    """DiT-B dims (768 x 12, 12 heads): 85M in attention + MLP, as the paper's 86M; adaLN-zero adds 6
    D^2/block."""
    with torch.device("meta"):
        model = DiT(input_dim=15, cond_dim=4096, hidden_dim=768, depth=12, num_heads=12)
    body = sum(count_parameters(b.attn) + count_parameters(b.mlp) for b in model.blocks)
    adaln = sum(count_parameters(b.adaLN_modulation) for b in model.blocks)
    assert 84e6 < body < 86e6
    assert 42e6 < adaln < 43e6
    assert 130e6 < count_parameters(model) < 135e6


def test_every_parameter_has_a_dimension_and_old_scalar_checkpoints_load() -> None:
    """FSDP refuses 0-d parameters; checkpoints saved when pos_scale was 0-d still load (reshaped)."""
    model = _dit()
    assert all(p.dim() >= 1 for p in model.parameters())
    state = model.state_dict()
    state["pos_scale"] = torch.tensor(0.5)  # the old 0-d layout
    model.load_state_dict(state)
    assert model.pos_scale.shape == (1,) and model.pos_scale.item() == 0.5
