"""Batch helpers for policy tests."""

from __future__ import annotations

from typing import Any

#: What ``lerobot-eval`` gives a policy after preprocessing: cameras, state,
#: language tokens and the task; the env
#: provides neither the state history nor the subgoal trace.
INFERENCE_KEYS = (
    "observation.images.static",
    "observation.images.gripper",
    "observation.state",
    "observation.language.tokens",
    "observation.language.attention_mask",
    "task",
)


def inference_observation(batch: dict[str, Any]) -> dict[str, Any]:
    """The inference-time subset of a preprocessed training batch."""
    return {key: batch[key] for key in INFERENCE_KEYS}
