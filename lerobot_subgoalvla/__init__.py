"""SubgoalVLA for LeRobot 0.6: the policy, the CALVIN environment and the CALVIN data path.

Importing the package itself is cheap (no torch, no LeRobot): the command-line tools that need neither start
in well under a second, and env worker processes stay light. The public names below are loaded on first
access; asking for any of them also registers the plugin with LeRobot (``lerobot_subgoalvla.plugin``).
"""

from __future__ import annotations

import importlib
import logging
from typing import Any

__version__ = "0.1.0"

#: public name -> module that defines it
_LAZY_NAMES = {
    "CalvinEnvConfig": "lerobot_subgoalvla.envs.calvin.configs",
    "SubgoalVLAConfig": "lerobot_subgoalvla.policies.subgoalvla.configuration_subgoalvla",
    "SubgoalVLAPolicy": "lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla",
    "make_subgoalvla_pre_post_processors": "lerobot_subgoalvla.policies.subgoalvla.processor_subgoalvla",
}

__all__: list[str] = ["__version__", *_LAZY_NAMES]


def __getattr__(name: str) -> Any:
    if name not in _LAZY_NAMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    importlib.import_module("lerobot_subgoalvla.plugin")
    value = getattr(importlib.import_module(_LAZY_NAMES[name]), name)
    globals()[name] = value
    return value


logging.getLogger(__name__).addHandler(logging.NullHandler())
