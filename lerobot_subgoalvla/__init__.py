"""SubgoalVLA for LeRobot 0.6: the policy, the CALVIN environment and the CALVIN data path.

Importing this package registers the policy type ``subgoalvla`` and the env type ``calvin`` with LeRobot.
"""

import logging

from lerobot_subgoalvla.envs.calvin.configs import CalvinEnvConfig  # registers "calvin"
from lerobot_subgoalvla.policies.subgoalvla.configuration_subgoalvla import (
    SubgoalVLAConfig,  # registers "subgoalvla"
)
from lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla import SubgoalVLAPolicy
from lerobot_subgoalvla.policies.subgoalvla.processor_subgoalvla import make_subgoalvla_pre_post_processors

__version__ = "0.1.0"

__all__: list[str] = [
    "__version__",
    "CalvinEnvConfig",
    "SubgoalVLAConfig",
    "SubgoalVLAPolicy",
    "make_subgoalvla_pre_post_processors",
]

logging.getLogger(__name__).addHandler(logging.NullHandler())
