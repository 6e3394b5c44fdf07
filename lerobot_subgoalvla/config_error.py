"""Errors whose one-line message must reach the user of LeRobot's CLIs.

``ConfigError``: a bad ``--policy.*`` / ``--env.*`` value, with a message that reaches the user.

LeRobot parses its command line with draccus, which replaces any ``ValueError`` raised while a config is built
with a generic "Couldn't instantiate class ... using the given arguments" (and, for ``--env.*``, a traceback).
draccus's own ``DecodingError`` passes through untouched, and LeRobot prints it as one ``error: ...`` line
with exit code 1. So config validation raises this subclass of it, whose text is just the message (naming the
flag and the allowed values).

``DatasetContractError``: data (a training dataset's features, an env's observations, a checkpoint's weights)
that does not fit the policy. LeRobot finds it after parsing, in ``make_policy``, and lets it end the process
with a traceback; the plugin installs a ``sys.excepthook`` (:func:`install_one_line_excepthook`) that prints
this error type as one ``error: ...`` line and exits 1, and leaves every other exception to the previous hook.
A ``ConfigError`` found after parsing (a ``--policy.dtype`` that asks for an autocast the training step does
not get) is printed the same way.
"""

from __future__ import annotations

import logging
import sys

from draccus.utils import DecodingError

logger = logging.getLogger("lerobot_subgoalvla")


class ConfigError(DecodingError):
    """A bad config value; ``str(error)`` is the message."""

    def __init__(self, message: str) -> None:
        super().__init__((), message)


class DatasetContractError(ValueError):
    """A dataset or env feature the policy needs is missing or mis-shaped; ``str(error)`` is the fix."""


def install_one_line_excepthook() -> None:
    """Print an uncaught :class:`DatasetContractError` or :class:`ConfigError` (one found after parsing,
    such as a precision the training step does not get) as one line (exit status 1, as any uncaught error)."""
    previous = sys.excepthook
    if getattr(previous, "_subgoalvla_one_line", False):
        return

    def hook(exc_type, exc, traceback) -> None:
        if issubclass(exc_type, DatasetContractError | ConfigError):
            logger.error("error: %s", exc)
        else:
            previous(exc_type, exc, traceback)

    hook._subgoalvla_one_line = True  # type: ignore[attr-defined]
    sys.excepthook = hook
