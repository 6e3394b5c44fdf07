"""The policy's own count of optimizer steps: each training step's keyed RNG, and what a loaded count means.

The count is saved with the weights (``SubgoalVLAPolicy.optimizer_steps``), so a resumed run keeps its stage
and its draws; these helpers keep that bookkeeping out of the policy class.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator

import torch

logger = logging.getLogger(__name__)


@contextlib.contextmanager
def seeded_rng(seed: int, device: torch.device) -> Iterator[None]:
    """Fork torch's RNG (CPU, and ``device``'s if it is a GPU), seed it, restore it on exit."""
    gpus = [device.index or 0] if device.type == "cuda" else []
    with torch.random.fork_rng(devices=gpus, device_type="cuda"):
        torch.manual_seed(seed)
        yield


def log_loaded_step(step: int, stage_now: str, configured_stage: str, switch: int | None) -> None:
    """Say where a loaded policy's step count stands at its first training step: a finished policy given to a
    new run with ``--policy.path`` would otherwise train stage II only, silently."""
    if step == 0:
        return
    if stage_now == "stage2" and configured_stage == "stage1":
        logger.warning(
            "SubgoalVLA: training starts at the loaded policy's optimizer step %d, past "
            "--policy.stage2_start_step=%d, so this run trains stage II only. Right for --resume; to "
            "train a finished policy from stage I again, set --policy.stage2_start_step beyond %d "
            "(docs/policy.md, 'Training a finished policy further')",
            step,
            switch,
            step,
        )
    else:
        logger.info("SubgoalVLA: training continues from the loaded policy's optimizer step %d", step)
