"""How SubgoalVLA fits itself to a dataset or env: cameras, state, window, angles (one line when it can't).

The policy is dataset-agnostic. What it learns from the data:

- **cameras**: every ``VISUAL`` input feature, in the order of the dataset's (or env's) features, or the
  subset ``--policy.camera_keys`` names, in that order. Their views sit side by side in the vision tower's
  square image (``backbone.prepare_pixel_values``), so the order is part of the trained model.
- **state and action**: any dimension (``observation.state`` (p,), ``action`` (A,)).
- **window** (``contract.window``): the dataset's trace metadata (``contract.metadata``) says how its
  ``observation.state_history`` / ``observation.subgoal_trace`` were cut; unset config values adopt it, set
  ones must agree with it.
- **angles**: wrapped-angle normalisation only where the dataset's metadata or the user says so, checked
  against the state's dimension before anything is built.

Errors are :class:`DatasetContractError` (one line through LeRobot's CLIs) naming the feature and the fix.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

from lerobot.configs import FeatureType

from lerobot_subgoalvla.config_error import DatasetContractError
from lerobot_subgoalvla.contract.keys import (
    ACTION_KEY,
    ENV_STATE_KEY,
    STATE_HISTORY_KEY,
    STATE_KEY,
    SUBGOAL_TRACE_KEY,
    TRACE_COLUMNS,
)
from lerobot_subgoalvla.contract.metadata import ProprioMetadata, check_angle_dims

logger = logging.getLogger(__name__)

#: the two commands that write the trace columns.
ADD_TRACES_COMMAND = "subgoalvla-add-traces --repo-id <id> --root <dataset> --output-root <new dataset>"
CONVERT_CALVIN_COMMAND = "subgoalvla-convert-calvin <CALVIN_DIR> --repo-id <id>"


class DatasetFitting:
    """The config's side of fitting a dataset or env (module docstring); a mixin of ``SubgoalVLAConfig``,
    whose fields (``input_features``, ``camera_keys``, ``state_angle_dims``, the window) it reads."""

    @property
    def image_features_in_order(self) -> list[str]:
        """The camera keys the policy reads, in the order their views are laid out (``camera_keys``)."""
        if self.camera_keys is not None:
            return list(self.camera_keys)
        inputs = self.input_features or {}
        return [key for key, feature in inputs.items() if feature.type is FeatureType.VISUAL]

    @property
    def images_per_sample(self) -> int:
        """Images the vision tower encodes per sample: one per camera with
        ``backbone.camera_layout=separate``, one in all side by side."""
        return len(self.image_features_in_order) if self.backbone.camera_layout == "separate" else 1

    def check_features(self) -> None:
        """Cameras, state and action exist and fit; history/trace inputs, when present, are state sequences.

        The state history and the subgoal trace are only needed for training; ``set_dataset_feature_metadata``
        checks them against the dataset (the env provides state + cameras only, and the policy builds the
        history itself at inference).
        """
        inputs = self.input_features or {}
        visual = [key for key, feature in inputs.items() if feature.type is FeatureType.VISUAL]
        problems = [f"the state {STATE_KEY!r}"] if STATE_KEY not in inputs else []
        problems += ["a camera (an image or video feature)"] if not visual else []
        problems += [f"the action {ACTION_KEY!r}"] if self.action_feature is None else []
        if problems:
            raise DatasetContractError(
                f"SubgoalVLA needs {' and '.join(problems)}, which the dataset/env does not provide "
                f"(its features: {sorted(inputs)})"
            )
        unknown = [key for key in self.camera_keys or () if key not in visual]
        if unknown:
            raise DatasetContractError(
                f"--policy.camera_keys names {unknown}, which are not cameras of the dataset/env; "
                f"its cameras are {visual}"
            )
        if self.environment_state_weight > 0 and ENV_STATE_KEY not in inputs:
            raise DatasetContractError(
                f"--policy.environment_state_weight={self.environment_state_weight} regresses "
                f"{ENV_STATE_KEY!r}, which the dataset does not have (its features: {sorted(inputs)}); "
                "set --policy.environment_state_weight=0"
            )
        state_dim = inputs[STATE_KEY].shape[-1]
        if self.state_angle_dims is not None:
            _check_angle_dims(self.state_angle_dims, state_dim, "--policy.state_angle_dims")
        for key in TRACE_COLUMNS:
            if key in inputs:
                self._check_sequence(key, tuple(inputs[key].shape), state_dim)

    def set_dataset_feature_metadata(self, features: Mapping[str, Mapping[str, Any]]) -> None:
        """LeRobot hook: ``make_policy`` calls it with the training dataset's features
        (``LeRobotDatasetMetadata.features``) before building the policy. Checks the data contract and adopts
        the dataset's window and angles into the unset config fields."""
        required = (STATE_KEY, ACTION_KEY, STATE_HISTORY_KEY, SUBGOAL_TRACE_KEY)
        missing = [key for key in required if key not in features]
        if not any(feature.get("dtype") in ("image", "video") for feature in features.values()):
            missing.append("a camera (an image or video feature)")
        if missing:
            fix = (
                f"add the trace columns with `{ADD_TRACES_COMMAND}`"
                if STATE_KEY in features
                else "SubgoalVLA plans the robot's own future states, so the dataset needs observation.state"
            )
            raise DatasetContractError(f"the training dataset lacks {', '.join(missing)}; {fix}")
        state_dim = tuple(features[STATE_KEY]["shape"])[-1]
        for key in TRACE_COLUMNS:
            self._check_sequence(key, tuple(features[key]["shape"]), state_dim)
        metadata = ProprioMetadata.from_features(features)
        if metadata is None:
            raise DatasetContractError(
                f"the dataset's {SUBGOAL_TRACE_KEY!r} carries no window metadata (it was written before "
                f"lerobot-subgoalvla 0.2); convert it again with `{CONVERT_CALVIN_COMMAND}` (CALVIN) or "
                f"write "
                f"the columns anew from the original dataset with `{ADD_TRACES_COMMAND}`"
            )
        _adopt_window(self, metadata)
        _adopt_angles(self, metadata, state_dim)

    def _check_sequence(self, key: str, shape: tuple[int, ...], state_dim: int) -> None:
        """``key`` is (steps, p); the history has h steps, the trace at least M."""
        if len(shape) != 2 or shape[1] != state_dim:
            raise DatasetContractError(
                f"dataset feature {key!r} has shape {shape}, expected (steps, {state_dim}); write it again "
                f"with `{ADD_TRACES_COMMAND}`"
            )
        if key == STATE_HISTORY_KEY and shape[0] != self.state_history_len:
            raise DatasetContractError(
                f"dataset feature {key!r} has {shape[0]} steps but --policy.state_history_len="
                f"{self.state_history_len}; set the flag to {shape[0]}"
            )
        if key == SUBGOAL_TRACE_KEY and shape[0] < self.subgoal_trace_len:
            raise DatasetContractError(
                f"dataset feature {key!r} has {shape[0]} steps but --policy.subgoal_trace_len="
                f"{self.subgoal_trace_len}; lower the flag to at most {shape[0]}"
            )


def _adopt_window(config: DatasetFitting, metadata: ProprioMetadata) -> None:
    window = metadata.window
    for name, dataset_value in (("state_stride", window.stride), ("subgoal_trace_start", window.trace_start)):
        value = getattr(config, name)
        if value is None:
            setattr(config, name, dataset_value)
        elif value != dataset_value:
            raise DatasetContractError(
                f"--policy.{name}={value} but the dataset's trace columns were cut with {dataset_value} "
                f"(its window: {window.describe()}); drop the flag, or write the columns again with "
                f"`subgoalvla-add-traces` and the window you want"
            )


def _adopt_angles(config: DatasetFitting, metadata: ProprioMetadata, state_dim: int) -> None:
    if config.state_angle_dims is None:
        config.state_angle_dims = tuple(metadata.angle_dims)
        config.state_angle_home = tuple(metadata.angle_home)
    elif tuple(config.state_angle_dims) != tuple(metadata.angle_dims):
        logger.warning(
            "--policy.state_angle_dims=%s replaces the dataset's angle dims %s",
            list(config.state_angle_dims),
            list(metadata.angle_dims),
        )
    _check_angle_dims(config.state_angle_dims, state_dim, "the angle dims")


def _check_angle_dims(dims: tuple[int, ...], state_dim: int, source: str) -> None:
    """The contract's check, raised as the policy's one-line ``DatasetContractError``."""
    try:
        check_angle_dims(dims, state_dim, source)
    except ValueError as error:
        raise DatasetContractError(str(error)) from None


def dataset_instructions(dataset_meta: Any) -> list[str]:
    """Every instruction a policy trained on this dataset should know: its tasks and its metadata's extra
    instructions (e.g. a benchmark's evaluation phrasing)."""
    tasks = [] if dataset_meta.tasks is None else [str(task) for task in dataset_meta.tasks.index]
    metadata = ProprioMetadata.from_features(dataset_meta.features)
    return tasks + list(metadata.instructions if metadata is not None else ())
