"""``ConfigError``: a bad ``--policy.*`` / ``--env.*`` value, with a message that reaches the user.

LeRobot parses its command line with draccus, which replaces any ``ValueError`` raised while a config is built
with a generic "Couldn't instantiate class ... using the given arguments" (and, for ``--env.*``, a traceback).
draccus's own ``DecodingError`` passes through untouched, and LeRobot prints it as one ``error: ...`` line
with exit code 1. So config validation raises this subclass of it, whose text is just the message (naming the
flag and the allowed values).
"""

from __future__ import annotations

from draccus.utils import DecodingError


class ConfigError(DecodingError):
    """A bad config value; ``str(error)`` is the message."""

    def __init__(self, message: str) -> None:
        super().__init__((), message)
