"""What a dataset records about its trace columns, and where: ``ProprioMetadata``.

A dataset made by ``subgoalvla-add-traces`` or ``subgoalvla-convert-calvin`` carries one block,
``features["observation.subgoal_trace"]["info"]["subgoalvla"]`` in ``meta/info.json``:

- the window its history and trace columns were cut with (``window.TraceWindow``) and the dataset's fps;
- which ``observation.state`` dimensions are wrapping angles, and the orientation they are measured from
  (CALVIN's TCP Euler angles; most robots have none);
- extra instructions the policy's word vocabulary must cover besides the dataset's own tasks (CALVIN's
  evaluation instructions differ from its training annotations);
- the command that wrote it (a name, never a local path: the block is published with the dataset).

Why inside the feature: LeRobot keeps a feature's ``info`` dict as it is, hands the features to the policy's
``set_dataset_feature_metadata`` hook before the policy is built, and warns about nothing, whereas an unknown
top-level field of ``info.json`` is dropped with a warning at every load.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from lerobot_subgoalvla.contract.keys import STATE_KEY, SUBGOAL_TRACE_KEY
from lerobot_subgoalvla.contract.window import TraceWindow

#: the key of the block inside the trace feature's ``info``.
METADATA_KEY = "subgoalvla"


def check_angle_dims(dims: Sequence[int], state_dim: int, source: str) -> None:
    """ValueError, one line naming ``source``, when an angle index is outside a ``state_dim``-dim state."""
    bad = [d for d in dims if not 0 <= d < state_dim]
    if bad:
        raise ValueError(
            f"{source} {list(dims)} do not fit the {state_dim}-dim {STATE_KEY} (index {bad[0]} is out of "
            f"range); give indices in 0..{state_dim - 1}, or [] for none"
        )


@dataclass(frozen=True)
class ProprioMetadata:
    """The trace columns' metadata (module docstring).

    Args:
        window: how ``observation.state_history`` / ``observation.subgoal_trace`` were cut.
        fps: the dataset's frame rate (the window's frames are at this rate).
        angle_dims: indices of wrapping angles in ``observation.state`` (empty: none).
        angle_home: the orientation each angle is measured from, radians (one per ``angle_dims`` entry).
        instructions: extra instructions for the policy's vocabulary (e.g. a benchmark's evaluation ones).
        writer: the command that wrote the columns.
    """

    window: TraceWindow
    fps: float
    angle_dims: tuple[int, ...] = ()
    angle_home: tuple[float, ...] = ()
    instructions: tuple[str, ...] = ()
    writer: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if len(self.angle_dims) != len(self.angle_home):
            raise ValueError(
                f"angle settings: {len(self.angle_dims)} angle dims but {len(self.angle_home)} home values"
            )

    def check_state_dim(self, state_dim: int, source: str) -> None:
        """Raise one line when an angle index does not exist in a ``state_dim``-dim state."""
        check_angle_dims(self.angle_dims, state_dim, source)

    def to_info(self) -> dict[str, Any]:
        """The JSON block (see ``METADATA_KEY``)."""
        return {
            **self.extra,
            "window": self.window.to_dict(),
            "fps": self.fps,
            "angle_dims": [int(d) for d in self.angle_dims],
            "angle_home": [float(h) for h in self.angle_home],
            "instructions": list(self.instructions),
            "writer": self.writer,
        }

    @classmethod
    def from_info(cls, block: Mapping[str, Any]) -> ProprioMetadata:
        known = {"window", "fps", "angle_dims", "angle_home", "instructions", "writer"}
        return cls(
            window=TraceWindow.from_dict(block["window"]),
            fps=block["fps"],
            angle_dims=tuple(int(d) for d in block.get("angle_dims", ())),
            angle_home=tuple(float(h) for h in block.get("angle_home", ())),
            instructions=tuple(block.get("instructions", ())),
            writer=block.get("writer", ""),
            extra={key: value for key, value in block.items() if key not in known},
        )

    @classmethod
    def from_features(cls, features: Mapping[str, Mapping[str, Any]]) -> ProprioMetadata | None:
        """The block of a dataset's features (``LeRobotDatasetMetadata.features``); None when it has none."""
        block = (features.get(SUBGOAL_TRACE_KEY) or {}).get("info", {}).get(METADATA_KEY)
        return None if block is None else cls.from_info(block)

    def attach(self, features: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
        """A copy of ``features`` whose trace feature carries this block."""
        out = {key: dict(value) for key, value in features.items()}
        trace = out[SUBGOAL_TRACE_KEY]
        trace["info"] = {**trace.get("info", {}), METADATA_KEY: self.to_info()}
        return out
