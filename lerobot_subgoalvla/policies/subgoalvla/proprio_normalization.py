"""One processor step that normalises every proprioceptive tensor the same way: state, history and trace.

Why one step of our own instead of LeRobot's ``normalizer_processor``:

- ``observation.state_history`` (h, p) and ``observation.subgoal_trace`` (M, p) are sequences of
  ``observation.state`` vectors. The policy builds the history at inference from normalised states and the
  planner predicts a trace in the same space as its queries, so all three must be normalised with the
  *state's* statistics. LeRobot's normaliser gives each column its own pooled statistics instead.
- Wrapping angles, where the dataset's metadata (or ``--policy.state_angle_dims``) declares them; a dataset
  without them is z-scored plainly. CALVIN's TCP orientation (``robot_obs[3:6]``, XYZ Euler angles) lives in
  (-pi, pi]. With the gripper
  pointing down the roll sits at +-pi, so a tiny real rotation wraps from +3.14 to -3.14 (48 wraps in 1726
  frames of the demo's data). Mean/std statistics of such a column are meaningless (std 2.2 rad) and a z-score
  turns the wrap into a jump of several standard deviations that the planner would have to predict 14-21 steps
  ahead. Here each angle is written as its wrapped difference to the robot's home orientation
  (``angle_home``), which is continuous wherever the gripper can go (the cut sits at a roll of 0 / yaw of
  +-pi, i.e. pointing up or turned half round), then divided by ``angle_scale``. No dataset statistic is used
  for the angles.

The step holds the statistics itself (saved in the pipeline's safetensors) and LeRobot's normaliser is told to
leave ``STATE`` features alone (``IDENTITY`` in the policy's normalisation mapping), so no reordering of steps
and no ``lerobot-train --policy.path`` statistics override can normalise a proprioceptive tensor twice or with
other numbers. :meth:`ProprioNormalizerProcessorStep.decode` inverts it (ghost-robot rendering of traces).

Dimension legend (the package's, ``__init__.py``): ``B`` batch, ``p`` proprio dim, ``h``
history steps, ``M`` trace steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import torch
from lerobot.configs import PipelineFeatureType, PolicyFeature
from lerobot.lerobot_types import RobotObservation
from lerobot.processor import ObservationProcessorStep, ProcessorStepRegistry
from torch import Tensor

from lerobot_subgoalvla.contract.keys import STATE_HISTORY_KEY, STATE_KEY, SUBGOAL_TRACE_KEY

#: Proprioceptive tensors normalised by the step: (B, p), (B, h, p), (B, M, p).
PROPRIO_KEYS = (STATE_KEY, STATE_HISTORY_KEY, SUBGOAL_TRACE_KEY)


def wrap_angle(angle: Tensor) -> Tensor:
    """Map angles (radians) to [-pi, pi)."""
    return torch.remainder(angle + math.pi, 2 * math.pi) - math.pi


@ProcessorStepRegistry.register(name="subgoalvla_proprio_normalizer")
@dataclass
class ProprioNormalizerProcessorStep(ObservationProcessorStep):
    """Normalise state, history and trace with the state's statistics; angles as wrapped offsets (module doc).

    Args:
        mean: (p,) per-dimension mean of ``observation.state`` (angle dimensions are ignored).
        std: (p,) per-dimension standard deviation of ``observation.state``.
        angle_dims: indices of the wrapping angles in the state vector (CALVIN: the TCP Euler angles 3, 4, 5).
        angle_home: the reference orientation the angles are measured from (one value per angle dim).
        angle_scale: radians per normalised unit for the angle dimensions.
        eps: added to ``std`` (a constant dimension stays finite).
    """

    mean: list[float] = field(default_factory=list)
    std: list[float] = field(default_factory=list)
    angle_dims: list[int] = field(default_factory=list)
    angle_home: list[float] = field(default_factory=list)
    angle_scale: float = 1.0
    eps: float = 1e-8

    def __post_init__(self) -> None:
        if len(self.mean) != len(self.std):
            raise ValueError(f"proprio normalizer: {len(self.mean)} means but {len(self.std)} stds")
        if len(self.angle_dims) != len(self.angle_home):
            raise ValueError("proprio normalizer: give one angle_home value per angle_dims entry")
        if self.mean and any(not 0 <= d < len(self.mean) for d in self.angle_dims):
            raise ValueError(
                f"proprio normalizer: angle_dims {self.angle_dims} outside a {len(self.mean)}-dim state"
            )

    @classmethod
    def from_stats(
        cls,
        stats: dict[str, Any] | None,
        angle_dims: tuple[int, ...],
        angle_home: tuple[float, ...],
        angle_scale: float,
    ) -> ProprioNormalizerProcessorStep:
        """Build from the dataset's ``observation.state`` statistics (``dataset.meta.stats[...]``)."""
        if stats is None:  # statistics come later from the saved state (from_pretrained)
            return cls(angle_dims=list(angle_dims), angle_home=list(angle_home), angle_scale=angle_scale)
        mean = torch.as_tensor(stats["mean"], dtype=torch.float64).flatten().tolist()
        std = torch.as_tensor(stats["std"], dtype=torch.float64).flatten().tolist()
        return cls(mean, std, list(angle_dims), list(angle_home), angle_scale)

    # Forward / inverse
    # ------------------------------------------------------------------------------------------
    def _tensors(self, like: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """mean (p,), std + eps (p,), angle mask (p,) bool and home offsets (p,) on ``like``'s device (cached:
        this runs on every env step and every batch)."""
        cache = self.__dict__.setdefault("_device_tensors", {})
        if like.device not in cache:
            cache[like.device] = self._build_tensors(like.device)
        return cache[like.device]

    def _build_tensors(self, device: torch.device) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        if not self.mean:
            raise ValueError(
                "subgoalvla_proprio_normalizer has no statistics: build the pre-processor with the dataset's "
                "stats, or load the policy_preprocessor.json saved with the checkpoint"
            )
        kwargs = {"dtype": torch.float32, "device": device}
        mean, std = torch.tensor(self.mean, **kwargs), torch.tensor(self.std, **kwargs) + self.eps
        is_angle = torch.zeros(len(self.mean), dtype=torch.bool, device=device)
        home = torch.zeros(len(self.mean), **kwargs)
        if self.angle_dims:
            is_angle[self.angle_dims] = True
            home[self.angle_dims] = torch.tensor(self.angle_home, **kwargs)
        return mean, std, is_angle, home

    def encode(self, values: Tensor) -> Tensor:
        """Raw proprioception (..., p) -> normalised (..., p)."""
        mean, std, is_angle, home = self._tensors(values)
        values = values.float()
        linear = (values - mean) / std
        angular = wrap_angle(values - home) / self.angle_scale
        return torch.where(is_angle, angular, linear)

    def decode(self, values: Tensor) -> Tensor:
        """Normalised (..., p) -> raw proprioception, angles wrapped to [-pi, pi)."""
        mean, std, is_angle, home = self._tensors(values)
        values = values.float()
        linear = values * std + mean
        angular = wrap_angle(values * self.angle_scale + home)
        return torch.where(is_angle, angular, linear)

    def observation(self, observation: RobotObservation) -> RobotObservation:
        observation = dict(observation)
        state = observation.get(STATE_KEY)
        for key in PROPRIO_KEYS:
            if key not in observation:
                continue
            values = torch.as_tensor(observation[key])
            # to_batch_processor batches the 1-D state but not the 2-D (h, p) / (M, p) sequences of one frame
            if key != STATE_KEY and state is not None and values.ndim == torch.as_tensor(state).ndim:
                values = values.unsqueeze(0)
            observation[key] = self.encode(values)
        return observation

    # Persistence
    # ------------------------------------------------------------------------------------------------
    def get_config(self) -> dict[str, Any]:
        return {
            "angle_dims": list(self.angle_dims),
            "angle_home": list(self.angle_home),
            "angle_scale": self.angle_scale,
            "eps": self.eps,
        }

    def state_dict(self) -> dict[str, Tensor]:
        if not self.mean:
            return {}
        return {"mean": torch.tensor(self.mean), "std": torch.tensor(self.std)}

    def load_state_dict(self, state: dict[str, Tensor]) -> None:
        if "mean" in state:
            self.mean = state["mean"].double().flatten().tolist()
            self.std = state["std"].double().flatten().tolist()
            self.__dict__.pop("_device_tensors", None)  # statistics changed: rebuild on next use
            self.__post_init__()

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        return features  # values change, shapes do not
