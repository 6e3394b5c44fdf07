"""What one SubgoalVLA training step keeps in memory, per preset: parameters and measured activations.

Parameters come from the real architecture built on the ``meta`` device (``architectures.py``, no weights).

Activations are MEASURED, not estimated from a formula: autograd's saved-tensor hooks
(``torch.autograd.graph.saved_tensors_hooks``) see every tensor a stage-I forward keeps for the backward pass;
we add up the bytes of their distinct storages. This counts exactly what the real code keeps (transformers'
attention, our cross-attention and DiTs with their repeated diffusion steps, autocast's choices) without
guessing constants. Tensors that are parameters are left out (they are the weights), and bf16 copies of
trainable weights that autocast saves are counted apart, once per step, because they do not grow with the
batch. With gradient checkpointing the hooks see only what survives the forward: the checkpointed blocks'
inputs (their inner tensors go to checkpoint's own hooks and are rebuilt in the backward pass).

``small`` and ``paper`` are too large to run on a CPU at full depth, so they are measured on a REDUCED-DEPTH
copy with the same widths, sequence lengths and resolution (random weights): the LLM truncated to 2 layers,
each cross-attention stack and each DiT with 2 blocks, the frozen vision tower with 2 layers (a frozen tower
saves nothing: no parameter of it needs a gradient and its input is the image). The identical blocks of one
stack each keep the same tensors, so with ``a(n_llm, n_pca, n_dit)`` the bytes measured with n blocks kept::

    per LLM layer     = a(2, 1, 1) - a(1, 1, 1)
    per PCA layer     = a(1, 2, 1) - a(1, 1, 1)     (planner + generator cross-attention together)
    per DiT block     = a(1, 1, 2) - a(1, 1, 1)     (planner + generator together)
    full depth        = a(1, 1, 1) + (k - 1) LLM + (L_pca - 1) PCA + (depth - 1) DiT

(k = m // 2 kept LLM layers; the presets give both heads the same depths.) ``tiny`` and ``laptop`` run at full
depth. Measured at batch 1 (activations are proportional to the batch; the few batch-independent tensors,
such as rotary tables and masks, are a few kB). With checkpointing, the backward pass rebuilds ONE block's
activations at a time; the peak adds the largest single block (``recompute_bytes``).

CPU caveats (``docs/memory.md``): CPU autocast casts nearly the same operations to bf16 as CUDA's; the CPU
attention kernel keeps, like CUDA's flash and memory-efficient kernels, no S x S attention matrix (checked:
no saved tensor of that shape).
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import weakref
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import torch
from architectures import architecture, build_model, make_config, training_batch
from torch import nn

from lerobot_subgoalvla.policies.subgoalvla.model import SubgoalVLAModel

#: presets measured at full depth (small random models); the others on the reduced copy.
FULL_DEPTH = ("tiny", "laptop")
#: blocks kept per stack in the reduced copy.
REDUCED = 2


@dataclass(frozen=True)
class Parameters:
    """Parameter counts of a preset's full-size model (stage I: everything but a frozen vision tower)."""

    total: int
    trainable: int
    #: parameters outside the blocks FSDP wraps (embeddings, projector, head embedders): the root unit.
    root: int
    #: parameters of the largest wrapped block (one FSDP unit).
    largest_block: int
    #: trainable parameters of the largest optimizer group (heads, projector or LLM, table 8): AdamW's
    #: multi-tensor step on a GPU allocates one temporary of this size (float32).
    largest_group: int
    #: the largest single parameter tensor (the LLM's embeddings): the temporary of AdamW's per-tensor step.
    largest_tensor: int


@dataclass(frozen=True)
class Activations:
    """Bytes a stage-I forward keeps for backward, per sample, and autocast's weight copies per step."""

    per_sample: int
    weight_copies: int
    #: the largest single block's activations (per sample): what checkpointing rebuilds at one time.
    recompute_bytes: int


def blocks(model: SubgoalVLAModel) -> dict[str, nn.ModuleList]:
    """The repeated blocks, by stack: the ones FSDP wraps and gradient checkpointing recomputes."""
    stacks = {
        "llm": model.backbone.vlm.language_model.layers,
        "vision": model.backbone.vlm.vision_tower.vision_model.encoder.layers,
    }
    for name in ("planner_aggregator", "generator_aggregator", "planner", "generator"):
        stacks[name] = getattr(model, name).blocks
    return stacks


def count_parameters(preset: str) -> Parameters:
    model = build_model(preset, "meta")
    total = sum(p.numel() for p in model.parameters())
    trainable = sum(p.numel() for p in model.parameters() if p.requires_grad)
    per_block = [sum(p.numel() for p in b.parameters()) for s in blocks(model).values() for b in s]
    bb = model.backbone
    groups = [model.head_parameters(), bb.projector_parameters(), bb.language_model_parameters()]
    largest_group = max(sum(p.numel() for p in g if p.requires_grad) for g in groups)
    largest_tensor = max(p.numel() for p in model.parameters() if p.requires_grad)
    return Parameters(total, trainable, total - sum(per_block), max(per_block), largest_group, largest_tensor)


# ------------------------------------------------------------------------------------------------------------
# Saved-tensor measurement
# ------------------------------------------------------------------------------------------------------------
def _is_weight_copy(tensor: torch.Tensor) -> bool:
    """A dtype cast of a trainable parameter (autocast's bf16 weights), possibly seen through a view (a linear
    layer saves the transposed weight): single-input nodes back to ToCopy, right after AccumulateGrad."""
    fn = tensor.grad_fn
    for _ in range(4):
        if fn is None:
            return False
        inputs = [next_fn for next_fn, _ in fn.next_functions if next_fn is not None]
        if fn.name() == "ToCopyBackward0":
            return len(inputs) == 1 and inputs[0].name().endswith("AccumulateGrad")
        if len(inputs) != 1:
            return False
        fn = inputs[0]
    return False


def saved_bytes(model: SubgoalVLAModel, batch: dict[str, torch.Tensor], bf16: bool) -> tuple[int, int]:
    """(activation bytes, weight-copy bytes) a stage-I forward of ``model`` keeps for the backward pass.

    Counted while alive: a tensor saved by an operation whose result is then discarded (a check inside
    transformers, say) is released with that operation, and its address may be reused by a later tensor;
    each packed tensor therefore holds its storage's count until autograd drops it.
    """
    weights = {p.untyped_storage().data_ptr() for p in model.parameters()}
    live: dict[int, list[int]] = {}  # storage address -> [references, bytes, kind (0 activation, 1 copy)]
    totals = [0, 0]

    def release(key: int) -> None:
        entry = live[key]
        entry[0] -= 1
        if entry[0] == 0:
            totals[entry[2]] -= entry[1]
            del live[key]

    def pack(tensor: torch.Tensor) -> torch.Tensor:
        storage = tensor.untyped_storage()
        key = storage.data_ptr()
        if not key or key in weights:
            return tensor
        if key not in live:
            live[key] = [0, storage.nbytes(), int(_is_weight_copy(tensor))]
            totals[live[key][2]] += storage.nbytes()
        live[key][0] += 1
        weakref.finalize(tensor, release, key)
        return tensor

    model.train()
    torch.manual_seed(0)  # the same timesteps, noise and dropout in every run
    with (
        torch.autograd.graph.saved_tensors_hooks(pack, lambda tensor: tensor),
        torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16),
    ):
        loss = model.compute_losses(batch, "stage1")["loss"]
    counted = (totals[0], totals[1])  # what the backward pass would find
    del loss  # frees the graph
    _release_memory()
    return counted


def _release_memory() -> None:
    """Hand freed heap pages back to the OS between runs (glibc keeps them otherwise and the RSS adds up)."""
    gc.collect()
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").malloc_trim(0)


def set_checkpointing(model: SubgoalVLAModel, enabled: bool) -> None:
    """Switch gradient checkpointing on or off on a built model (the config flag does it at build time)."""
    if enabled:
        model.enable_gradient_checkpointing()
        return
    model.backbone.vlm.gradient_checkpointing_disable()
    for name in ("planner_aggregator", "generator_aggregator", "planner", "generator"):
        getattr(model, name).gradient_checkpointing = False


@contextmanager
def kept_blocks(model: SubgoalVLAModel, llm: int, pca: int, dit: int) -> Iterator[None]:
    """Run the model with only the first ``llm`` / ``pca`` / ``dit`` blocks of each stack, then restore."""
    lm = model.backbone.vlm.language_model
    owners = {"llm": (lm, "layers", llm)}
    for name, n in (
        ("planner_aggregator", pca),
        ("generator_aggregator", pca),
        ("planner", dit),
        ("generator", dit),
    ):
        owners[name] = (getattr(model, name), "blocks", n)
    full = {name: list(getattr(owner, attribute)) for name, (owner, attribute, _) in owners.items()}
    layers = lm.config.num_hidden_layers
    try:
        for name, (owner, attribute, n) in owners.items():
            setattr(owner, attribute, nn.ModuleList(full[name][:n]))
        lm.config.num_hidden_layers = llm  # transformers iterates layers[: num_hidden_layers]
        yield
    finally:
        for name, (owner, attribute, _) in owners.items():
            setattr(owner, attribute, nn.ModuleList(full[name]))
        lm.config.num_hidden_layers = layers


def reduced_model(preset: str) -> SubgoalVLAModel:
    """The preset's widths with 2 blocks per stack (see the module docstring); random weights on the CPU."""
    torch.manual_seed(0)
    config = make_config(preset)
    if preset in FULL_DEPTH:
        return build_model(preset, "cpu", config)
    if not config.backbone.freeze_vision_tower:
        raise ValueError(
            f"{preset}: the reduced copy assumes a frozen vision tower (it saves no activations)"
        )
    config.backbone.layer = REDUCED
    for head in (config.planner, config.generator):
        head.depth = REDUCED
    for attention in (config.planner_attention, config.generator_attention):
        attention.num_layers = REDUCED
    return build_model(
        preset, "cpu", config, architecture(preset, text_layers=REDUCED, vision_layers=REDUCED)
    )


def full_depths(preset: str) -> tuple[int, int, int]:
    """(k, cross-attention layers, DiT depth) of the preset at full size."""
    config = make_config(preset)
    if config.planner.depth != config.generator.depth or (
        config.planner_attention.num_layers != config.generator_attention.num_layers
    ):
        raise ValueError(f"{preset}: planner and generator stacks differ in depth; measure them apart")
    k = build_model(preset, "meta").backbone.layer
    return k, config.planner_attention.num_layers, config.planner.depth


#: (LLM layers, cross-attention layers, DiT blocks) kept for the base run and for each stack's increment.
_SHAPES = {"base": (1, 1, 1), "llm": (2, 1, 1), "pca": (1, 2, 1), "dit": (1, 1, 2)}


def _stack_runs(
    model: SubgoalVLAModel, batch: dict[str, torch.Tensor], bf16: bool
) -> dict[str, tuple[int, int]]:
    """``saved_bytes`` with one block per stack ("base") and with two blocks in one stack."""
    runs = {}
    for name, shape in _SHAPES.items():
        with kept_blocks(model, *shape):
            runs[name] = saved_bytes(model, batch, bf16)
    return runs


def measure_activations(preset: str, model: SubgoalVLAModel, bf16: bool) -> dict[bool, Activations]:
    """Per-sample activations and per-step weight copies of the full-depth preset, without (False) and with
    (True) gradient checkpointing; see the module docstring."""
    torch.manual_seed(0)
    batch = training_batch(model, "cpu", batch=1)
    out = {}
    for checkpointing in (False, True):
        set_checkpointing(model, checkpointing)
        runs = _stack_runs(model, batch, bf16)
        if preset in FULL_DEPTH:
            act, copies = saved_bytes(model, batch, bf16)
        else:
            k, pca, dit = full_depths(preset)
            scale = {"llm": k - 1, "pca": pca - 1, "dit": dit - 1}
            base = runs["base"]
            act = base[0] + sum(n * (runs[s][0] - base[0]) for s, n in scale.items())
            copies = base[1] + sum(n * (runs[s][1] - base[1]) for s, n in scale.items())
        if not checkpointing:
            # the backward pass of a checkpointed model rebuilds one block at a time: the largest plain one
            # (PCA and DiT increments hold a planner AND a generator block: an upper bound)
            largest = max(runs[s][0] - runs["base"][0] for s in ("llm", "pca", "dit"))
        out[checkpointing] = Activations(act, copies, largest)
    set_checkpointing(model, False)
    return out
