"""SubgoalVLA model benchmark: parameters, FLOPs and latency per action chunk, per preset.

Usage::

    python benchmarks/policy_benchmark.py                                   # tiny/small/paper sizes, tiny
    latency python benchmarks/policy_benchmark.py --presets tiny small --latency-presets tiny small --device
    cuda python benchmarks/policy_benchmark.py --threads 1 --runs 50

Nothing is downloaded. ``small`` and ``paper`` are instantiated from their architectures' known configs
(``llava-hf/llava-interleave-qwen-0.5b-hf``: SigLIP-so400m-384 + Qwen1.5-0.5B; ``llava-hf/llava-1.5-7b-hf``:
CLIP ViT-L/14-336 + LLaMA-2-7B) on the ``meta`` device for parameters and FLOPs, and with random weights on
``--device`` for latency (latency does not depend on weight values). FLOPs are counted by
``torch.utils.flop_counter`` for batch size 1: vision tower + projector, the k kept LLM layers, and each head
as (cross-attention once) + (DiT forward x DDIM steps, doubled batch when classifier-free guidance is on).
Latency is the median over ``--runs`` chunks of: backbone (``encode``), planner (``plan``), generator
(``generate``), measured side by side in one process.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import torch
from architectures import ACTION_DIM, STATE_DIM, build_model, fake_inputs
from torch import nn
from torch.utils.flop_counter import FlopCounterMode

from lerobot_subgoalvla.contract.keys import STATE_HISTORY_KEY
from lerobot_subgoalvla.policies.subgoalvla.model import SubgoalVLAModel


def count(params: list[nn.Parameter] | nn.Module | None) -> int:
    if params is None:
        return 0
    return sum(p.numel() for p in (params.parameters() if isinstance(params, nn.Module) else params))


def parameter_row(model: SubgoalVLAModel) -> dict[str, float]:
    bb = model.backbone
    lm = bb.vlm.language_model
    per_layer = count(lm.layers[0])
    return {
        "vision": count(bb.vision_parameters()),
        "projector": count(bb.projector_parameters()),
        "LLM kept (k layers)": count(bb.language_model_parameters()),
        "LLM all (m layers)": count(bb.language_model_parameters())
        + per_layer * (bb.num_llm_layers - bb.layer),
        "PCA planner": count(model.planner_aggregator),
        "PCA generator": count(model.generator_aggregator),
        "DiT planner": count(model.planner),
        "DiT generator": count(model.generator),
        "total (built)": count(model),
    }


def flops(fn: Callable[[], object]) -> int:
    with FlopCounterMode(display=False) as counter:
        fn()
    return counter.get_total_flops()


def head_flops(model: SubgoalVLAModel, which: str, hidden: torch.Tensor, mask: torch.Tensor) -> int:
    """One cross-attention pass + the DiT forwards of one DDIM sampling run (batch 1)."""
    cfg = model.config
    history = torch.zeros(1, cfg.state_history_len, STATE_DIM, device="meta")
    if which == "planner":
        aggregator, dit, objective, queries = (
            model.planner_aggregator,
            model.planner,
            model.planner_objective,
            history,
        )
        x = torch.zeros(1, cfg.subgoal_trace_len, STATE_DIM, device="meta")
    else:
        trace = torch.zeros(1, cfg.subgoal_trace_len, STATE_DIM, device="meta")
        queries = model._generator_queries(history, trace if model.planner is not None else None)
        aggregator, dit, objective = model.generator_aggregator, model.generator, model.generator_objective
        x = torch.zeros(1, cfg.chunk_size, ACTION_DIM, device="meta")
    features, features_mask = aggregator(queries, hidden, mask)
    cfg_batch = 1 if objective.guidance_scale == 1.0 else 2
    t = torch.zeros(cfg_batch, dtype=torch.long, device="meta")
    dit_flops = flops(lambda: dit(x.expand(cfg_batch, -1, -1), t, features.expand(cfg_batch, -1, -1)))
    return flops(lambda: aggregator(queries, hidden, mask)) + objective.num_inference_steps * dit_flops


def flop_row(model: SubgoalVLAModel) -> dict[str, float]:
    """FLOPs per chunk (batch 1). The backbone is split into vision+projector and k decoder layers because the
    LLaVA placeholder scatter and the causal-mask helpers need real values (not available on the meta
    device)."""
    vlm, spec = model.backbone.vlm, model.backbone.input_spec
    pixels = torch.zeros(1, 3, spec.image_size, spec.image_size, device="meta")
    length = spec.num_image_tokens + model.config.backbone.max_instruction_tokens
    embeds = torch.zeros(1, length, model.backbone.hidden_size, device="meta")
    mask = torch.ones(1, length, dtype=torch.long, device="meta")
    vision = flops(lambda: vlm.get_image_features(pixel_values=pixels))
    lm = vlm.language_model  # one decoder layer x k: the LLM's mask helpers need real values, not meta ones
    positions = torch.arange(length, device="meta").unsqueeze(0)
    rotary = lm.rotary_emb(embeds, positions)
    layer = lm.layers[0]
    llm = len(lm.layers) * flops(lambda: layer(embeds, position_ids=positions, position_embeddings=rotary))
    hidden = embeds.float()
    row = {"vision+projector": vision, "LLM": llm}
    row["planner"] = head_flops(model, "planner", hidden, mask.bool()) if model.planner is not None else 0
    row["generator"] = head_flops(model, "generator", hidden, mask.bool())
    row["total"] = sum(row.values())
    return row


def synchronize(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def latency_row(model: SubgoalVLAModel, device: str, runs: int) -> dict[str, float]:
    """Median milliseconds per chunk of backbone / planner / generator, measured in one loop.

    ``chunk`` is wall-clock time; ``chunk CPU`` is this process's CPU time for the same chunk, which on a
    shared, oversubscribed CPU estimates the latency the chunk would have on an idle core (CPU device only).
    """
    batch = fake_inputs(model, device)
    history = batch[STATE_HISTORY_KEY]
    times: dict[str, list[float]] = {
        "backbone": [],
        "planner": [],
        "generator": [],
        "chunk": [],
        "chunk CPU": [],
    }
    with torch.inference_mode():
        for i in range(runs + 3):  # 3 warm-up chunks
            synchronize(device)
            cpu0, t0 = time.process_time(), time.perf_counter()
            hidden, mask = model.encode(batch)
            synchronize(device)
            t1 = time.perf_counter()
            trace = model.plan(hidden, mask, history) if model.planner is not None else None
            synchronize(device)
            t2 = time.perf_counter()
            model.generate(hidden, mask, history, trace)
            synchronize(device)
            t3, cpu3 = time.perf_counter(), time.process_time()
            if i >= 3:
                values = (t1 - t0, t2 - t1, t3 - t2, t3 - t0, cpu3 - cpu0)
                for key, value in zip(times, values, strict=True):
                    times[key].append(1000 * value)
    return {key: statistics.median(values) for key, values in times.items()}


def print_table(title: str, rows: dict[str, dict[str, float]], scale: float, unit: str) -> None:
    columns = list(next(iter(rows.values())))
    print(f"\n{title}")
    print("| preset | " + " | ".join(columns) + " |")
    print("|---" * (len(columns) + 1) + "|")
    for preset, row in rows.items():
        print(f"| {preset} | " + " | ".join(f"{row[c] / scale:,.3f}{unit}" for c in columns) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--presets",
        nargs="+",
        default=["tiny", "laptop", "small", "paper"],
        choices=["tiny", "laptop", "small", "paper"],
    )
    parser.add_argument(
        "--latency-presets",
        nargs="*",
        default=["tiny", "laptop"],
        choices=["tiny", "laptop", "small", "paper"],
    )
    parser.add_argument("--device", default="cpu", help="device for the latency runs (cpu, cuda)")
    parser.add_argument("--runs", type=int, default=30, help="chunks timed per preset (median reported)")
    parser.add_argument("--threads", type=int, default=None, help="torch intra-op threads on CPU")
    args = parser.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    params, flop_rows = {}, {}
    for preset in args.presets:
        model = build_model(preset, "meta")
        label = f"{preset} (k={model.backbone.layer}/m={model.backbone.num_llm_layers})"
        params[label] = parameter_row(model)
        flop_rows[label] = flop_row(model)
    print_table("Parameters (millions)", params, 1e6, "M")
    print_table("FLOPs per action chunk, batch 1 (GFLOPs)", flop_rows, 1e9, "")
    latency = {}
    for preset in args.latency_presets:
        torch.manual_seed(0)
        latency[f"{preset} ({args.device}, {torch.get_num_threads()} thr)"] = latency_row(
            build_model(preset, args.device), args.device, args.runs
        )
    if latency:
        print_table(f"Latency per chunk, median of {args.runs} (ms)", latency, 1.0, "")


if __name__ == "__main__":
    main()
