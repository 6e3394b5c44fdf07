"""Discovery shim for LeRobot's ``register_third_party_plugins()``.

LeRobot imports every installed distribution whose name starts with ``lerobot_policy_`` by that exact name.
Importing this module registers the ``subgoalvla`` policy type, its processor steps and scheduler, and the
``calvin`` env type (``lerobot_subgoalvla.plugin``). Nothing else lives here.
"""

from lerobot_subgoalvla.plugin import *  # noqa: F403  (re-export the registered surface)
from lerobot_subgoalvla.plugin import __all__  # noqa: F401
