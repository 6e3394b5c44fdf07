"""Memory plan per preset: what a training step needs per GPU, with and without the memory-saving options.

Usage::

    python benchmarks/memory_plan.py                        # all presets, batch 32 per GPU, 8 GPUs
    python benchmarks/memory_plan.py --presets tiny small --batch-size 16 --gpus 4

Nothing is downloaded: parameters come from the real architectures on the ``meta`` device and activations are
measured on the CPU (``memory_model.py`` explains how). All four presets took 5 minutes on one thread and a
peak of 22 GB of RAM (``paper``'s reduced copy: 1.4 B parameters in float32, 16 forward passes); leave
``paper`` out on a smaller machine.

Training state, bytes per parameter (AdamW as LeRobot builds it, ``P`` all parameters, ``T`` trainable ones,
stage I: everything but a frozen vision tower): weights 4 P (float32; accelerate's bf16 mode is autocast and
keeps float32 weights, so the same), gradients 4 T, AdamW's two moments 8 T. The peak per GPU adds, per
option:

- one GPU: the activations of the batch, B x per-sample + (bf16) autocast's bf16 weight copies saved for
  backward; or, at the optimizer step, AdamW's temporary (4 x the largest group: torch's multi-tensor AdamW on
  a GPU) when that is larger (the activations are freed before the step).
- DDP (every GPU holds everything): the same + 4 T of DDP's gradient buckets (accelerate keeps DDP's default
  separate copy).
- gradient checkpointing (``--policy.gradient_checkpointing=true``): the checkpointed activations, plus one
  block's full activations rebuilt at a time in the backward pass.
- ZeRO-2 (FSDP ``SHARD_GRAD_OP`` over N GPUs): weights, gradients and AdamW state split N ways; the full
  weights in the compute dtype (bf16: 2 P, or float32 4 P) stay gathered from forward to backward.
- ZeRO-3 (FSDP ``FULL_SHARD``, configs/accelerate/fsdp_paper.yaml): everything split N ways; gathered at a
  time: the root unit (embeddings, projector, head embedders; kept for the whole step) and two blocks
  (current + prefetched), in the compute dtype; AdamW's temporary shrinks N ways.

Not included: the CUDA context and allocator reserve (about 1-3 GB per GPU), dataloader pinned memory, NCCL
buffers. ``docs/memory.md`` lists what only a GPU run can confirm.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import torch
from architectures import make_config
from memory_model import Activations, Parameters, count_parameters, measure_activations, reduced_model

GB, MB = 1e9, 1e6
PRESETS = ("tiny", "laptop", "small", "paper")


@dataclass(frozen=True)
class Plan:
    """Everything measured for one preset, in its own training precision."""

    preset: str
    bf16: bool
    params: Parameters
    #: {precision "fp32"/"bf16": {checkpointing: Activations}}
    activations: dict[str, dict[bool, Activations]]

    @property
    def state_bytes(self) -> tuple[float, float, float]:
        """(weights, gradients, AdamW moments) in bytes, float32 everywhere."""
        return 4.0 * self.params.total, 4.0 * self.params.trainable, 8.0 * self.params.trainable

    def batch_activations(self, batch: int, checkpointing: bool, with_copies: bool) -> float:
        act = self.activations["bf16" if self.bf16 else "fp32"][checkpointing]
        total = batch * act.per_sample + (act.weight_copies if with_copies else 0)
        return total + (batch * act.recompute_bytes if checkpointing else 0)


def ddp_peak(plan: Plan, batch: int, checkpointing: bool) -> float:
    weights, grads, adam = plan.state_bytes
    temp = 4.0 * plan.params.largest_group
    return weights + 2 * grads + adam + max(plan.batch_activations(batch, checkpointing, plan.bf16), temp)


def single_gpu_peak(plan: Plan, batch: int, checkpointing: bool) -> float:
    """One GPU: accelerate wraps nothing in DDP, so no gradient buckets."""
    return ddp_peak(plan, batch, checkpointing) - plan.state_bytes[1]


def zero2_peak(plan: Plan, batch: int, checkpointing: bool, gpus: int) -> float:
    weights, grads, adam = plan.state_bytes
    gathered = (2.0 if plan.bf16 else 4.0) * plan.params.total
    temp = 4.0 * plan.params.largest_group / gpus
    act = plan.batch_activations(batch, checkpointing, with_copies=False)  # FSDP casts the weights itself
    return (weights + grads + adam) / gpus + gathered + max(act, temp)


def zero3_peak(plan: Plan, batch: int, checkpointing: bool, gpus: int) -> float:
    weights, grads, adam = plan.state_bytes
    unit_bytes = 2.0 if plan.bf16 else 4.0
    gathered = unit_bytes * (plan.params.root + 2 * plan.params.largest_block)
    temp = 4.0 * plan.params.largest_group / gpus
    act = plan.batch_activations(batch, checkpointing, with_copies=False)
    return (weights + grads + adam) / gpus + gathered + max(act, temp)


def measure(preset: str) -> Plan:
    params = count_parameters(preset)
    model = reduced_model(preset)
    activations = {
        name: measure_activations(preset, model, bf16) for name, bf16 in (("fp32", False), ("bf16", True))
    }
    bf16 = make_config(preset).dtype == "bfloat16"
    return Plan(preset, bf16, params, activations)


def print_tables(plans: list[Plan], batch: int, gpus: int) -> None:
    print("\nParameters and training state (AdamW, float32 weights/gradients/moments)")
    print("| preset | total | trainable | weights | gradients | AdamW moments | sum |")
    print("|---|---|---|---|---|---|---|")
    for plan in plans:
        w, g, a = plan.state_bytes
        print(
            f"| {plan.preset} | {plan.params.total / 1e6:,.1f}M | {plan.params.trainable / 1e6:,.1f}M | "
            f"{w / GB:.2f} GB | {g / GB:.2f} GB | {a / GB:.2f} GB | {(w + g + a) / GB:.2f} GB |"
        )
    print("\nActivations kept for backward, per sample (MB, measured; stage I)")
    print(
        "| preset | fp32 | fp32 + ckpt | bf16 | bf16 + ckpt | bf16 weight copies / step "
        "| rebuilt block (bf16) |"
    )
    print("|---|---|---|---|---|---|---|")
    for plan in plans:
        fp32, bf16 = plan.activations["fp32"], plan.activations["bf16"]
        print(
            f"| {plan.preset} | {fp32[False].per_sample / MB:,.1f} | {fp32[True].per_sample / MB:,.1f} | "
            f"{bf16[False].per_sample / MB:,.1f} | {bf16[True].per_sample / MB:,.1f} | "
            f"{bf16[False].weight_copies / MB:,.0f} | {bf16[False].recompute_bytes / MB:,.1f} |"
        )
    print(
        f"\nPeak per GPU, batch {batch} per GPU, the preset's precision "
        f"(GB; {gpus} GPUs for the sharded columns)"
    )
    print(
        "| preset | precision | 1 GPU + ckpt | DDP | DDP + ckpt | ZeRO-2 + ckpt | FSDP full shard "
        "| FSDP full shard + ckpt |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for plan in plans:
        cells = [
            single_gpu_peak(plan, batch, True),
            ddp_peak(plan, batch, False),
            ddp_peak(plan, batch, True),
            zero2_peak(plan, batch, True, gpus),
            zero3_peak(plan, batch, False, gpus),
            zero3_peak(plan, batch, True, gpus),
        ]
        precision = "bf16 autocast" if plan.bf16 else "fp32"
        print(f"| {plan.preset} | {precision} | " + " | ".join(f"{c / GB:,.1f}" for c in cells) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--presets", nargs="+", default=list(PRESETS), choices=PRESETS)
    parser.add_argument("--batch-size", type=int, default=32, help="samples per GPU (table 8: 32)")
    parser.add_argument("--gpus", type=int, default=8, help="GPUs the sharded options split over (paper: 8)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads for the measurements")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    plans = [measure(preset) for preset in args.presets]
    print_tables(plans, args.batch_size, args.gpus)


if __name__ == "__main__":
    main()
