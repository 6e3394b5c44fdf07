"""What differs between the LeRobot versions the policy supports (0.6.1 and main, version 0.6.2).

Each helper detects the feature, never the version number (docs/lerobot_versions.md lists every difference):

- Saving: 0.6.1's ``PreTrainedPolicy._save_pretrained(save_directory, state_dict=None)`` writes a state
  dict the caller gathered (its FSDP checkpointing passes one); main's ``_save_pretrained(save_directory)``
  takes no ``state_dict`` and gathers a sharded (FSDP2) policy itself. :data:`BASE_SAVE_TAKES_STATE_DICT`
  tells which one is installed; :func:`write_state_dict` writes a given state dict where the base cannot.
- The model card: a method of ``PreTrainedPolicy`` in 0.6.1, the free function
  ``lerobot.common.train_utils.generate_model_card(config)`` in main (:func:`model_card`).
- Mixed precision: 0.6.1's ``lerobot-train`` turns the policy's ``dtype`` into accelerate's autocast; main
  reads only ``--accelerator.mixed_precision``. :func:`require_autocast` stops a training step that runs
  without the autocast the config asks for, instead of letting it train in float32 unnoticed.
"""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import TYPE_CHECKING

import torch
from huggingface_hub import save_torch_state_dict
from lerobot.policies import PreTrainedPolicy
from torch import Tensor

from lerobot_subgoalvla.config_error import ConfigError

if TYPE_CHECKING:
    from huggingface_hub import ModelCard
    from lerobot.configs import PreTrainedConfig

#: True on LeRobot 0.6.1, whose ``PreTrainedPolicy._save_pretrained`` takes a pre-gathered ``state_dict``.
BASE_SAVE_TAKES_STATE_DICT = "state_dict" in inspect.signature(PreTrainedPolicy._save_pretrained).parameters

#: The ``dtype`` values that mean mixed precision: their autocast dtype and accelerate's name for them.
MIXED_PRECISION = {"bfloat16": (torch.bfloat16, "bf16"), "float16": (torch.float16, "fp16")}


def write_state_dict(config: PreTrainedConfig, state_dict: dict[str, Tensor], save_directory: Path) -> None:
    """Write ``config.json`` and ``state_dict`` as one ``model.safetensors``, as 0.6.1's base does."""
    config._save_pretrained(save_directory)
    # One file whatever the size: loading reads model.safetensors only, never a sharded index.
    save_torch_state_dict(state_dict, str(save_directory), max_shard_size="1TB")


def model_card(policy: PreTrainedPolicy, dataset_repo_id: str) -> ModelCard:
    """LeRobot's model card for ``policy``, naming ``dataset_repo_id`` as its training data.

    Rendering it validates it with the Hub, so it needs a connection.
    """
    config = policy.config
    legacy = getattr(policy, "generate_model_card", None)
    if legacy is not None:  # LeRobot 0.6.1
        return legacy(dataset_repo_id, config.type, config.license, config.tags)
    from lerobot.common.train_utils import generate_model_card

    card = generate_model_card(config)  # the card of the config alone: no training run, no dataset metadata
    card.data.datasets = dataset_repo_id
    return card


def require_autocast(dtype: str | None, device_type: str) -> None:
    """Raise when ``dtype`` asks for mixed precision but the training forward runs without that autocast.

    Args:
        dtype: the policy's ``dtype`` (``bfloat16``, ``float16``, ``float32`` or None).
        device_type: the device the forward runs on (``cuda``, ``cpu``).

    Raises:
        ConfigError: with the flag that turns the autocast on, or the one that trains in full precision.
    """
    if dtype not in MIXED_PRECISION:
        return
    wanted, accelerate_name = MIXED_PRECISION[dtype]
    if torch.is_autocast_enabled(device_type) and torch.get_autocast_dtype(device_type) == wanted:
        return
    raise ConfigError(
        f"--policy.dtype={dtype} asks for {accelerate_name} mixed precision, but the training step runs "
        f"without {dtype} autocast (LeRobot after 0.6.1 takes it from --accelerator.mixed_precision only): "
        f"pass --accelerator.mixed_precision={accelerate_name}, or --policy.dtype=float32 for full precision"
    )
