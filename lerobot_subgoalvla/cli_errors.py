"""How every ``subgoalvla-*`` command ends on a failure: one log line naming the cause, a non-zero exit.

``user_errors()`` wraps a command's work. Expected failures (bad input, a missing or unwritable path, a full
or read-only disk: ``ValueError``, ``OSError`` and its ``FileNotFoundError`` / ``NotADirectoryError`` /
``PermissionError`` kin, ``RuntimeError``) become one ``ERROR`` line and exit code 1. Ctrl-C becomes one line
saying how to continue (exit 130, the shell's code for SIGINT). Anything else is a bug and keeps its
traceback.
"""

from __future__ import annotations

import contextlib
import logging
import sys
from collections.abc import Iterator

USER_ERRORS = (ValueError, OSError, RuntimeError)
#: Exit status of a command stopped by Ctrl-C (128 + SIGINT), as shells report it.
INTERRUPTED = 130


@contextlib.contextmanager
def user_errors(logger: logging.Logger, on_interrupt: str = "interrupted") -> Iterator[None]:
    """Turn expected failures inside the block into one log line and ``SystemExit(1)`` (130 on Ctrl-C).

    Args:
        logger: the command's logger.
        on_interrupt: what to tell the user after Ctrl-C (e.g. how to resume).
    """
    try:
        yield
    except USER_ERRORS as error:
        logger.error("%s", error)
        sys.exit(1)
    except KeyboardInterrupt:
        logger.error("%s", on_interrupt)
        sys.exit(INTERRUPTED)
