"""Loading checkpoints: a mismatch raises instead of leaving weights random; older layouts load exactly."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file, save_file

from lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla import SubgoalVLAPolicy

DIT_MLP_OUT = re.compile(r"(model\.(planner|generator)\.blocks\.\d+\.mlp\.)2\.")


def _saved(make_config, make_policy_and_processors, path: Path) -> tuple[SubgoalVLAPolicy, dict]:
    policy, _, _ = make_policy_and_processors(make_config())
    policy.save_pretrained(path)
    return policy, load_file(path / "model.safetensors")


def test_a_checkpoint_missing_weights_fails_loudly(make_config, make_policy_and_processors, tmp_path) -> None:
    _, weights = _saved(make_config, make_policy_and_processors, tmp_path)
    dropped = next(k for k in weights if DIT_MLP_OUT.match(k))
    del weights[dropped]
    save_file(weights, tmp_path / "model.safetensors")
    with pytest.raises(ValueError, match=rf"{re.escape(str(tmp_path))}: .*do not match.*strict=False"):
        SubgoalVLAPolicy.from_pretrained(tmp_path)
    loose = SubgoalVLAPolicy.from_pretrained(tmp_path, strict=False)  # LeRobot's behaviour, on request
    assert loose is not None


def test_a_checkpoint_from_before_the_dropout_removal_loads_exactly(
    make_config, make_policy_and_processors, tmp_path
) -> None:
    """Why: such checkpoints stored each DiT MLP's output layer at index 3 and had no training seed; loaded
    non-strictly they acted on random weights (different behaviour with every --seed)."""
    policy, weights = _saved(make_config, make_policy_and_processors, tmp_path)
    legacy = {DIT_MLP_OUT.sub(r"\g<1>3.", k): v for k, v in weights.items() if k != "training_seed"}
    assert sum(".mlp.3." in k for k in legacy) > 0
    save_file(legacy, tmp_path / "model.safetensors")
    for seed in (0, 1):
        torch.manual_seed(seed)
        reloaded = SubgoalVLAPolicy.from_pretrained(tmp_path)
        original = policy.state_dict()
        for key, value in reloaded.state_dict().items():
            if key != "training_seed":
                assert torch.equal(value, original[key]), key
