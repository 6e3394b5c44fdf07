"""Discovery shim for LeRobot's ``register_third_party_plugins()``.

LeRobot imports every installed distribution whose name starts with ``lerobot_policy_`` by that exact name.
Importing this module imports :mod:`lerobot_subgoalvla`, which registers the ``subgoalvla`` policy type and the
``calvin`` env type. Nothing else lives here.
"""

from lerobot_subgoalvla import *  # noqa: F403  (re-export the public surface)
from lerobot_subgoalvla import __all__  # noqa: F401
