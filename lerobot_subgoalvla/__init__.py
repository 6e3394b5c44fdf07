"""SubgoalVLA for LeRobot 0.6: the policy, the CALVIN environment and the CALVIN data path.

Importing this package registers the policy type ``subgoalvla`` and the env type ``calvin`` with LeRobot.
"""

import logging

__version__ = "0.1.0"

__all__: list[str] = ["__version__"]

logging.getLogger(__name__).addHandler(logging.NullHandler())
