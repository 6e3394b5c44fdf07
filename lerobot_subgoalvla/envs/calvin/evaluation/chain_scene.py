"""Symbolic chain states -> simulator states (docs/calvin.md 4.2): the fixed robot start and each chain's
scene_obs.

Split from ``chains.py`` (the chain sampler) by concern. The block layout of a symbolic state is seeded with
``RandomState(h)``, ``h`` = FNV-1 32-bit with initial value 0 over the UTF-16-LE bytes of
``str(state.values())``
as CPython prints it: re-implementations that hash UTF-8 or start from the FNV offset basis get other layouts.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import numpy as np

from lerobot_subgoalvla.calvin_vocab import BLOCK_COLORS

#: Symbolic state keys and initial values, in CALVIN's product order (spec 4.1). Order matters: it fixes the
#: state indices (hence the per-state seeds) and the string that is hashed for the scene layout.
SYMBOLIC_VALUES: Mapping[str, tuple[Any, ...]] = MappingProxyType(
    {
        "led": (0, 1),
        "lightbulb": (0, 1),
        "slider": ("right", "left"),
        "drawer": ("closed", "open"),
        "red_block": ("table", "slider_right", "slider_left"),
        "blue_block": ("table", "slider_right", "slider_left"),
        "pink_block": ("table", "slider_right", "slider_left"),
        "grasped": (0,),
    }
)

#: The fixed robot state every chain starts from (spec 4.2; gripper open).
EVAL_ROBOT_OBS: np.ndarray = np.array(
    [0.02586889, -0.2313129, 0.5712808, 3.09045411, -0.02908596, 1.50013585,
     0.07999963, -1.21779124, 1.03987629, 2.11978254, -2.34205014, -0.87015899, 1.64119093, 0.55344928, 1.0]
)  # fmt: skip
EVAL_ROBOT_OBS.setflags(write=False)

_BLOCK_SLIDER_LEFT = (-2.40851662e-01, 9.24044687e-02, 4.60990009e-01)
_BLOCK_SLIDER_RIGHT = (7.03416330e-02, 9.24044687e-02, 4.60990009e-01)
_BLOCK_TABLE = (
    (5.00000896e-02, -1.20000177e-01, 4.59990009e-01),
    (2.29995412e-01, -1.19995140e-01, 4.59990010e-01),
)
_BLOCK_YAW_RANGE = (np.pi / 2 - np.pi / 8, np.pi / 2 + np.pi / 8)


def fnv1_32(data: bytes) -> int:
    """FNV-1 32-bit with initial value 0 (pyhash ``fnv1_32()``'s default seed, not the offset basis)."""
    h = 0
    for byte in data:
        h = (h * 16777619) & 0xFFFFFFFF
        h ^= byte
    return h


def state_seed(state: Mapping[str, Any]) -> int:
    """CALVIN's per-state seed: pyhash over ``str(state.values())`` (UTF-16-LE bytes, CPython 3.8 repr)."""
    text = "dict_values([" + ", ".join(repr(_plain(v)) for v in state.values()) + "])"
    return fnv1_32(text.encode("utf-16-le"))


def _plain(value: Any) -> int | str:
    """Python int/str as CALVIN's state holds them (a numpy int would print as ``np.int64(1)``)."""
    return value if isinstance(value, str) else int(value)


def scene_obs_for_state(state: Mapping[str, Any]) -> np.ndarray:
    """The (24,) ``scene_obs`` of a symbolic initial state (spec 4.2; blocks in red, blue, pink slots)."""
    for key in (f"{color}_block" for color in BLOCK_COLORS):
        if state[key] not in SYMBOLIC_VALUES[key]:
            raise ValueError(
                f"{key}={state[key]!r} is not an initial value; use one of {SYMBOLIC_VALUES[key]}"
            )
    rs = np.random.RandomState(state_seed(state))
    table_slots = [np.array(p) for p in _BLOCK_TABLE]
    rs.shuffle(table_slots)
    obs = np.zeros(24)
    obs[0] = 0.28 if state["slider"] == "left" else 0.0
    obs[1] = 0.22 if state["drawer"] == "open" else 0.0
    obs[3] = 0.088 if state["lightbulb"] == 1 else 0.0
    obs[4], obs[5] = state["lightbulb"], state["led"]
    table_slot_of = {"red": 0, "blue": 1 if state["red_block"] == "table" else 0, "pink": 1}
    for slot, color in enumerate(BLOCK_COLORS):
        where = state[f"{color}_block"]
        base = 6 + 6 * slot
        if where == "table":
            obs[base : base + 3] = table_slots[table_slot_of[color]]
        else:
            obs[base : base + 3] = _BLOCK_SLIDER_RIGHT if where == "slider_right" else _BLOCK_SLIDER_LEFT
        obs[base + 5] = rs.uniform(*_BLOCK_YAW_RANGE)  # drawn in red, blue, pink order after the shuffle
    return obs
