"""Worker for the sharded-training test: ``torchrun --nproc_per_node 2 sharded_training.py CONFIG OUT``.

accelerate refuses FSDP on a CPU-only machine (``Accelerator(cpu=True)`` always means multi-CPU DDP), so
``lerobot-train`` cannot be launched sharded here. This worker does what lerobot-train 0.6.1 does under an
FSDP accelerate config, step by step, on two gloo processes: it builds the policy and its optimizer groups
first, wraps the policy with FSDP1 exactly as accelerate's ``prepare`` would with the given accelerate YAML
(accelerate's own plugin turns the YAML's class names into the auto-wrap policy), then runs the training step
of lerobot-train (forward, backward, ``clip_grad_norm_`` of the FSDP module, AdamW step, ``update()``) across
the stage I -> II switch, and gathers the full model and optimizer state dicts (``full_state_dict``). The same
steps run under plain DDP from the same weights on the same batches; rank 0 saves both final state dicts and
the logged losses to OUT for the test to compare.
"""

from __future__ import annotations

import copy
import json
import os
import sys
from pathlib import Path

import torch
import torch.distributed as dist
import yaml
from accelerate.utils import FullyShardedDataParallelPlugin
from lerobot.configs import FeatureType, PolicyFeature
from lerobot.utils.constants import OBS_LANGUAGE_ATTENTION_MASK, OBS_LANGUAGE_TOKENS
from safetensors.torch import save_file
from torch.distributed.fsdp import (
    FullOptimStateDictConfig,
    FullStateDictConfig,
    FullyShardedDataParallel,
    StateDictType,
)
from torch.nn.parallel import DistributedDataParallel

from lerobot_subgoalvla.policies.subgoalvla.backbone import tokenize_instructions
from lerobot_subgoalvla.policies.subgoalvla.configuration_subgoalvla import SubgoalVLAConfig
from lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla import SubgoalVLAPolicy
from lerobot_subgoalvla.policies.subgoalvla.tokenizer import build_tiny_tokenizer, vocabulary_words

P, A, STEPS, SWITCH, PER_RANK = 15, 7, 4, 2, 2
INSTRUCTIONS = ["open the drawer", "push the red block to the left", "turn on the lightbulb", "lift it"]


def make_config() -> SubgoalVLAConfig:
    config = SubgoalVLAConfig(
        preset="tiny",
        device="cpu",
        input_features={
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(P,)),
            "observation.images.static": PolicyFeature(type=FeatureType.VISUAL, shape=(3, 32, 32)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(A,))},
        stage2_start_step=SWITCH,
        gradient_checkpointing=True,
        optimizer_lr_heads=3e-3,
    )
    config.backbone.vocabulary = list(vocabulary_words(INSTRUCTIONS))
    config.planner.repeated_diffusion_steps = config.generator.repeated_diffusion_steps = 2
    return config


def make_batch(policy: SubgoalVLAPolicy, step: int, rank: int) -> dict[str, torch.Tensor]:
    """This rank's share of the global batch of ``step`` (the same on every run)."""
    generator = torch.Generator().manual_seed(100 * step + rank)
    tokenizer = build_tiny_tokenizer(policy.config.backbone.vocabulary)
    ids, mask = tokenize_instructions(
        tokenizer, INSTRUCTIONS[rank * PER_RANK : (rank + 1) * PER_RANK], 12, policy.model.backbone.input_spec
    )
    return {
        "observation.images.static": torch.rand(PER_RANK, 3, 32, 32, generator=generator),
        OBS_LANGUAGE_TOKENS: ids,
        OBS_LANGUAGE_ATTENTION_MASK: mask,
        "observation.state_history": torch.randn(PER_RANK, 15, P, generator=generator),
        "observation.subgoal_trace": torch.randn(PER_RANK, 8, P, generator=generator),
        "action": torch.randn(PER_RANK, 15, A, generator=generator),
        "action_is_pad": torch.zeros(PER_RANK, 15, dtype=torch.bool),
    }


def fsdp_wrap(policy: SubgoalVLAPolicy, accelerate_yaml: Path) -> FullyShardedDataParallel:
    """FSDP1 with the YAML's settings, built the way accelerate's ``prepare`` builds it (no weight sync:
    both ranks start from the same seeded weights, and accelerate refuses the sync on CPU)."""
    fsdp = yaml.safe_load(accelerate_yaml.read_text())["fsdp_config"]
    plugin = FullyShardedDataParallelPlugin(
        fsdp_version=fsdp["fsdp_version"],
        sharding_strategy=fsdp["fsdp_sharding_strategy"],
        auto_wrap_policy=fsdp["fsdp_auto_wrap_policy"],
        transformer_cls_names_to_wrap=fsdp["fsdp_transformer_layer_cls_to_wrap"].split(","),
        use_orig_params=fsdp["fsdp_use_orig_params"],
        backward_prefetch=fsdp["fsdp_backward_prefetch"],
        state_dict_type=fsdp["fsdp_state_dict_type"],
        sync_module_states=False,
    )
    plugin.set_auto_wrap_policy(policy)
    return FullyShardedDataParallel(
        policy,
        sharding_strategy=plugin.sharding_strategy,
        auto_wrap_policy=plugin.auto_wrap_policy,
        backward_prefetch=plugin.backward_prefetch,
        use_orig_params=plugin.use_orig_params,
        device_id=torch.device("cpu"),
    )


def full_state_dict(model: FullyShardedDataParallel, optimizer: torch.optim.Optimizer) -> dict:
    """The full model state dict, gathered like LeRobot's ``gather_fsdp_state_dicts`` (a collective) but
    without its offload to CPU: on CPU-resident shards that offload segfaults (torch 2.11, gloo); on GPUs
    lerobot-train's own gather is used. The optimizer state is gathered too, keyed by parameter name, as the
    checkpoint needs it."""
    config = FullStateDictConfig(offload_to_cpu=False, rank0_only=False)
    optim_config = FullOptimStateDictConfig(offload_to_cpu=False, rank0_only=False)
    with FullyShardedDataParallel.state_dict_type(model, StateDictType.FULL_STATE_DICT, config, optim_config):
        state = model.state_dict()
        optim_state = FullyShardedDataParallel.optim_state_dict(model, optimizer)
    if not set(optim_state["state"]) <= set(state):
        raise RuntimeError("the gathered optimizer state is not keyed by the model's parameter names")
    return state


def train(policy: SubgoalVLAPolicy, sharded: Path | None, rank: int) -> tuple[dict, list[float], int]:
    """lerobot-train's steps; returns the full state dict, the losses and the number of FSDP units."""
    # the policy's optimizer preset and groups, built before wrapping, as lerobot-train does
    optimizer = policy.config.get_optimizer_preset().build(policy.get_optim_params())
    model = (
        fsdp_wrap(policy, sharded)
        if sharded
        else DistributedDataParallel(policy, find_unused_parameters=True)
    )
    losses = []
    for step in range(STEPS):
        loss, _ = model(make_batch(policy, step, rank))
        loss.backward()
        if sharded:
            model.clip_grad_norm_(policy.config.optimizer_grad_clip_norm)  # what accelerate calls under FSDP
        else:
            torch.nn.utils.clip_grad_norm_(model.parameters(), policy.config.optimizer_grad_clip_norm)
        optimizer.step()
        optimizer.zero_grad()
        policy.update()
        reduced = loss.detach().clone()
        dist.all_reduce(reduced)
        losses.append(reduced.item() / dist.get_world_size())
    if sharded:
        state = full_state_dict(model, optimizer)
        units = len(FullyShardedDataParallel.fsdp_modules(model))
    else:
        state, units = policy.state_dict(), 0
    return state, losses, units


def main() -> None:
    accelerate_yaml, out = Path(sys.argv[1]), Path(sys.argv[2])
    dist.init_process_group("gloo")
    rank = dist.get_rank()
    torch.manual_seed(0)
    reference = SubgoalVLAPolicy(make_config())
    twin = copy.deepcopy(reference)
    ddp_state, ddp_losses, _ = train(reference, None, rank)
    fsdp_state, fsdp_losses, units = train(twin, accelerate_yaml, rank)
    if rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        save_file({k: v.contiguous() for k, v in ddp_state.items()}, out / "ddp.safetensors")
        save_file({k: v.contiguous() for k, v in fsdp_state.items()}, out / "fsdp.safetensors")
        report = {"ddp_losses": ddp_losses, "fsdp_losses": fsdp_losses, "fsdp_units": units}
        (out / "report.json").write_text(json.dumps(report))
    dist.barrier()
    dist.destroy_process_group()


if __name__ == "__main__":
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    main()
