"""A saved SubgoalVLA checkpoint loaded for drawing what it plans: the policy with its processors, and the
inverse of its state normalisation (a predicted trace back in the dataset's state units).

Shared by the trace tools (``render_traces`` for CALVIN's ghost robots, ``trace_plot`` for any LeRobot env);
it imports no simulator.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from lerobot.configs import PreTrainedConfig
from lerobot.policies import get_policy_class, make_pre_post_processors

from lerobot_subgoalvla.policies.subgoalvla.proprio_normalization import ProprioNormalizerProcessorStep


def _proprio_normalizer(preprocessor: Any) -> ProprioNormalizerProcessorStep:
    """The pre-processor's ``subgoalvla_proprio_normalizer`` (it normalises state, history and trace)."""
    steps = [step for step in preprocessor.steps if isinstance(step, ProprioNormalizerProcessorStep)]
    if len(steps) != 1:
        raise ValueError(
            f"the pre-processor has {len(steps)} subgoalvla_proprio_normalizer steps, expected exactly one; "
            "load the policy_preprocessor.json saved with the checkpoint"
        )
    return steps[0]


def unnormalize_state(preprocessor: Any, tensor: torch.Tensor) -> torch.Tensor:
    """Invert the pre-processor's normalisation of ``observation.state`` on ``(..., p)`` rows.

    The exact inverse of :class:`ProprioNormalizerProcessorStep` with the statistics saved in the checkpoint,
    so a trace comes back in the dataset's ``observation.state`` units (declared angles wrapped to
    [-pi, pi)).
    """
    return _proprio_normalizer(preprocessor).decode(tensor)


def load_policy(policy_path: str | Path) -> tuple[Any, Any, Any]:
    """Load a saved SubgoalVLA checkpoint on the CPU: (policy, preprocessor, postprocessor).

    Raises:
        FileNotFoundError: ``policy_path`` is not a checkpoint directory (no ``config.json``).
        ValueError: the checkpoint is of another policy type.
    """
    import lerobot_subgoalvla.plugin  # noqa: F401  (registers the policy type before the config is parsed)

    path = Path(policy_path)
    if not (path / "config.json").is_file():
        raise FileNotFoundError(
            f"--policy-path {path}: no config.json there; pass a checkpoint directory such as "
            "outputs/train/<run>/checkpoints/last/pretrained_model"
        )
    cfg = PreTrainedConfig.from_pretrained(path)
    if cfg.type != "subgoalvla":
        raise ValueError(
            f"--policy-path {path}: a {cfg.type!r} checkpoint; only SubgoalVLA predicts subgoal traces"
        )
    cfg.device = "cpu"
    policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg)
    preprocessor, postprocessor = make_pre_post_processors(
        cfg, pretrained_path=str(path), preprocessor_overrides={"device_processor": {"device": "cpu"}}
    )
    return policy, preprocessor, postprocessor
