"""One real training step of a full-size preset on the CPU: its peak memory, measured, next to the plan's.

Usage (needs about 12 GB of free RAM for ``small``; run it alone, it measures the whole process)::

    OMP_NUM_THREADS=1 nice -n 19 python benchmarks/memory_step.py --preset small --batch-size 2

The model is the preset's real architecture with random weights (``architectures.py``, no download), in
float32, stage I (everything trains but the frozen vision tower), AdamW over the trainable parameters with
LeRobot's settings. Two steps run (forward, backward, gradient clipping, AdamW step, ``zero_grad``): the
first allocates AdamW's moments, the second is the steady state a training run repeats.

Measured: the process's resident memory (``/proc/self/statm``) after the imports (baseline) and after building
the model, and its peak (``resource.getrusage(RUSAGE_SELF).ru_maxrss``: the kernel's high-water mark of
resident pages, which includes the allocator's slack). Computed, as ``memory_plan.py`` does for a CPU:
weights + gradients + AdamW moments + the larger of the batch's activations (measured on the reduced copy
AFTER the peak was recorded) and AdamW's per-tensor temporary (torch's CPU AdamW updates one tensor at a
time).
"""

from __future__ import annotations

import argparse
import os
import resource
import time

import torch
from architectures import build_model, training_batch
from memory_model import count_parameters, measure_activations, reduced_model

GB = 1e9


def resident_bytes() -> int:
    """Current resident set size of this process."""
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def peak_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux reports KiB


def run_steps(preset: str, batch_size: int, steps: int) -> dict[str, float]:
    """Build the full-size model, train ``steps`` steps; resident memory at each point (bytes)."""
    torch.manual_seed(0)
    baseline = resident_bytes()
    model = build_model(preset, "cpu").train()
    built = resident_bytes()
    trainable = [p for p in model.parameters() if p.requires_grad]
    optimizer = torch.optim.AdamW(trainable, lr=1e-5, weight_decay=0.01)  # LeRobot's AdamW, one group
    batch = training_batch(model, "cpu", batch_size)
    start = time.perf_counter()
    for _ in range(steps):
        loss = model.compute_losses(batch, "stage1")["loss"]
        loss.backward()
        torch.nn.utils.clip_grad_norm_(trainable, 1.0)
        optimizer.step()
        optimizer.zero_grad()
    seconds = (time.perf_counter() - start) / steps
    return {
        "baseline": baseline,
        "built": built,
        "peak": peak_bytes(),
        "seconds": seconds,
        "loss": loss.item(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--preset", default="small", choices=["tiny", "laptop", "small", "paper"])
    parser.add_argument("--batch-size", type=int, default=2)
    parser.add_argument("--steps", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(1)
    measured = run_steps(args.preset, args.batch_size, args.steps)
    params = count_parameters(args.preset)
    activations = measure_activations(args.preset, reduced_model(args.preset), bf16=False)[False]
    weights, grads, adam = 4.0 * params.total, 4.0 * params.trainable, 8.0 * params.trainable
    act = args.batch_size * activations.per_sample
    temp = 4.0 * params.largest_tensor
    computed = weights + grads + adam + max(act, temp)
    grown = measured["peak"] - measured["baseline"]
    print(f"\n{args.preset}: one float32 training step on the CPU, batch {args.batch_size}")
    print("| quantity | measured | computed |")
    print("|---|---|---|")
    print(f"| resident after imports | {measured['baseline'] / GB:.2f} GB | |")
    print(
        f"| model built (weights) | {(measured['built'] - measured['baseline']) / GB:.2f} GB "
        f"| {weights / GB:.2f} GB |"
    )
    print(f"| gradients + AdamW moments | | {(grads + adam) / GB:.2f} GB |")
    print(f"| activations of the batch / AdamW temporary | | {act / GB:.2f} / {temp / GB:.2f} GB |")
    print(f"| training peak above the imports | {grown / GB:.2f} GB | {computed / GB:.2f} GB |")
    print(f"| difference | {100 * (grown - computed) / computed:+.1f} % | |")
    print(
        f"| seconds per step (1 thread), final loss | {measured['seconds']:.1f} s, {measured['loss']:.3f} | |"
    )


if __name__ == "__main__":
    main()
