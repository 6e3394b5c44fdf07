"""The shims that let one policy run on LeRobot 0.6.1 and on LeRobot main (``lerobot_compat.py``).

Saving under both ``_save_pretrained`` signatures, ``drop_queued_actions``, the FSDP2 wrap units, and the stop
when ``dtype`` asks for an autocast the training step does not get. The tests run on whichever LeRobot is
installed; the ones that need a LeRobot main feature skip on 0.6.1 (scripts/test_lerobot_main.sh runs them).
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from helpers.policy_batches import inference_observation
from helpers.tiny_training import run_tiny_training
from lerobot.configs.train import TrainPipelineConfig
from safetensors.torch import load_file

import lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla as modeling
from lerobot_subgoalvla.config_error import ConfigError
from lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla import SubgoalVLAPolicy

#: LeRobot main's lerobot-train has --accelerator.* (mixed precision from the flag, not the policy's dtype).
HAS_ACCELERATOR_FLAGS = "accelerator" in {f.name for f in dataclasses.fields(TrainPipelineConfig)}


# Saving ---------------------------------------------------------------------------------------------------
def _shifted(policy: SubgoalVLAPolicy) -> dict[str, torch.Tensor]:
    """A full state dict that differs from the policy's own: what a caller that gathered weights passes."""
    return {
        key: value + 1 if value.is_floating_point() else value for key, value in policy.state_dict().items()
    }


@pytest.mark.parametrize("base_takes_state_dict", [modeling.BASE_SAVE_TAKES_STATE_DICT, False])
def test_a_given_state_dict_is_saved_under_either_base_signature(
    make_config, make_policy_and_processors, tmp_path: Path, monkeypatch, base_takes_state_dict: bool
) -> None:
    """0.6.1's base writes the given dict; where the base takes none (main), the policy writes it itself."""
    monkeypatch.setattr(modeling, "BASE_SAVE_TAKES_STATE_DICT", base_takes_state_dict)
    policy, _, _ = make_policy_and_processors(make_config())
    given = _shifted(policy)
    policy.save_pretrained(tmp_path, state_dict=given)  # LeRobot 0.6.1's save_checkpoint passes one
    saved = load_file(tmp_path / "model.safetensors")
    assert saved.keys() == given.keys()
    for key, value in given.items():
        assert torch.equal(saved[key], value), key
    assert (tmp_path / "config.json").is_file()
    reloaded = SubgoalVLAPolicy.from_pretrained(tmp_path)
    assert torch.equal(reloaded.state_dict()["optimizer_steps"], given["optimizer_steps"])


def test_both_lerobot_call_forms_of_save_pretrained_hook_save_the_policy(
    make_config, make_policy_and_processors, tmp_path: Path
) -> None:
    """``_save_pretrained(dir)`` (main's call) and ``_save_pretrained(dir, state_dict=None)`` (0.6.1's)."""
    policy, _, _ = make_policy_and_processors(make_config())
    own = policy.state_dict()
    for name, call in [
        ("main", lambda d: policy._save_pretrained(d)),
        ("v061", lambda d: policy._save_pretrained(d, state_dict=None)),
    ]:
        directory = tmp_path / name
        directory.mkdir()
        call(directory)
        saved = load_file(directory / "model.safetensors")
        assert {key: torch.equal(saved[key], own[key]) for key in saved} == dict.fromkeys(own, True)
        assert (directory / "config.json").is_file()


# Queue dropping -------------------------------------------------------------------------------------------
def test_drop_queued_actions_empties_the_queue_and_keeps_the_history(
    make_config, make_policy_and_processors, raw_batch
) -> None:
    policy, pre, _ = make_policy_and_processors(make_config(n_action_steps=4))
    policy.eval()
    obs = inference_observation(pre(dict(raw_batch)))
    state = obs["observation.state"]
    histories: list[torch.Tensor] = []
    sample = policy.model.sample_actions
    policy.model.sample_actions = lambda batch, generator=None: (
        histories.append(batch["observation.state_history"].clone()) or sample(batch, generator)
    )
    for step in range(2):
        policy.select_action({**obs, "observation.state": state + 0.1 * step})
    assert len(histories) == 1 and len(policy._queue) == 2
    policy.drop_queued_actions()
    assert len(policy._queue) == 0
    policy.select_action({**obs, "observation.state": state + 0.2})
    assert len(histories) == 2  # a new chunk at once, not after the two queued actions
    torch.testing.assert_close(histories[-1][:, -3:], torch.stack([state + 0.1 * i for i in range(3)], dim=1))


def test_a_new_instruction_drops_the_queue_through_the_lerobot_hook(
    make_config, make_policy_and_processors, raw_batch, monkeypatch
) -> None:
    """The policy's own task-change check and LeRobot main's rollout use the same method."""
    policy, pre, _ = make_policy_and_processors(make_config(n_action_steps=4))
    policy.eval()
    obs = inference_observation(pre(dict(raw_batch)))
    drops = Counter()
    drop = policy.drop_queued_actions
    monkeypatch.setattr(policy, "drop_queued_actions", lambda: drops.update(["drop"]) or drop())
    policy.select_action(obs)
    policy.select_action(obs)
    assert drops["drop"] == 0
    policy.select_action({**obs, "task": ["open the drawer", *obs["task"][1:]]})
    assert drops["drop"] == 1


# FSDP2 wrap units -----------------------------------------------------------------------------------------
def test_fsdp_wrap_modules_are_the_blocks_of_the_built_model(make_config, make_policy_and_processors) -> None:
    cfg = make_config()
    policy, _, _ = make_policy_and_processors(cfg)
    declared = type(policy)._fsdp_wrap_modules
    units = [m for m in policy.modules() if type(m).__name__ in declared]
    counts = Counter(type(m).__name__ for m in units)
    assert counts == {
        "DiTBlock": cfg.planner.depth + cfg.generator.depth,
        "ProprioCrossAttentionBlock": cfg.planner_attention.num_layers + cfg.generator_attention.num_layers,
        "LlamaDecoderLayer": cfg.backbone.text_num_layers // 2,  # the LLM is cut after layer k = m // 2
        "CLIPEncoderLayer": cfg.backbone.vision_num_layers,
    }
    # No unit inside another (each parameter is sharded once), and the units hold most weights even of the
    # tiny model (78 %); the rest (embeddings, projector, final layers) stays in the root unit.
    inner = {id(sub) for m in units for sub in m.modules() if sub is not m}
    assert not any(id(m) in inner for m in units)
    in_units = sum(p.numel() for m in units for p in m.parameters())
    assert in_units > 0.7 * sum(p.numel() for p in policy.parameters())


def test_lerobot_main_takes_the_wrap_units_from_the_policy_class(
    make_config, make_policy_and_processors
) -> None:
    factory = pytest.importorskip("lerobot.distributed.factory", reason="LeRobot 0.6.1 has no FSDP2 path")
    policy, _, _ = make_policy_and_processors(make_config())
    plugin = SimpleNamespace(min_num_params=None, transformer_cls_names_to_wrap=None)
    factory.set_fsdp_wrap_modules(SimpleNamespace(state=SimpleNamespace(fsdp_plugin=plugin)), policy)
    assert plugin.transformer_cls_names_to_wrap == list(SubgoalVLAPolicy._fsdp_wrap_modules)
    present = {type(m).__name__ for m in policy.modules()}
    assert set(plugin.transformer_cls_names_to_wrap) <= present  # accelerate fails on a name it cannot find


# Mixed precision ------------------------------------------------------------------------------------------
def test_a_mixed_precision_dtype_without_its_autocast_stops_the_training_step(
    make_config, make_policy_and_processors, raw_batch
) -> None:
    policy, pre, _ = make_policy_and_processors(make_config(dtype="bfloat16"))
    batch = pre(dict(raw_batch))
    policy.train()
    with pytest.raises(
        ConfigError, match=r"pass --accelerator\.mixed_precision=bf16, or --policy\.dtype=float32"
    ):
        policy.forward(batch)
    with torch.autocast("cpu", dtype=torch.float16), pytest.raises(ConfigError):
        policy.forward(batch)  # an autocast of another dtype is not the one asked for
    with torch.autocast("cpu", dtype=torch.bfloat16):
        loss, _ = policy.forward(batch)
    assert torch.isfinite(loss)
    policy.eval()
    assert torch.isfinite(policy.forward(batch)[0])  # held-out loss: not a training step


def test_full_precision_needs_no_autocast(make_config, make_policy_and_processors, raw_batch) -> None:
    policy, pre, _ = make_policy_and_processors(make_config(dtype="float32"))
    policy.train()
    assert torch.isfinite(policy.forward(pre(dict(raw_batch)))[0])


def test_lerobot_train_gets_bf16_from_whichever_flag_this_lerobot_reads(
    tiny_dataset_root: Path, tmp_path
) -> None:
    """0.6.1: ``--policy.dtype=bfloat16`` alone; main: it stops in one line without the accelerator flag."""
    dtype = ["--policy.dtype=bfloat16"]
    if HAS_ACCELERATOR_FLAGS:
        stopped = run_tiny_training(tiny_dataset_root, "local/tiny_calvin", tmp_path / "no_flag", 1, dtype)
        assert stopped.returncode == 1
        assert "error: --policy.dtype=bfloat16 asks for bf16 mixed precision" in stopped.stderr
        assert "Traceback" not in stopped.stderr
        dtype.append("--accelerator.mixed_precision=bf16")
    result = run_tiny_training(tiny_dataset_root, "local/tiny_calvin", tmp_path / "bf16", 1, dtype)
    assert result.returncode == 0, (result.stdout + result.stderr)[-3000:]
