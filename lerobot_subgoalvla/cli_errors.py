"""How every ``subgoalvla-*`` command ends on a failure: one log line naming the cause, a non-zero exit.

``user_errors()`` wraps a command's work. Expected failures (bad input, a missing or unwritable path, a full
or read-only disk: ``ValueError``, ``OSError`` and its ``FileNotFoundError`` / ``NotADirectoryError`` /
``PermissionError`` kin, ``RuntimeError``) become one ``ERROR`` line and exit code 1. Ctrl-C becomes one line
saying how to continue (exit 130, the shell's code for SIGINT). Anything else is a bug and keeps its
traceback.

The checks every command shares live here too, so that one kind of bad value reads the same in every command:
``OneLineArgumentParser`` (a usage error is one line, exit 1, not argparse's usage block and exit 2) and
``require_at_least`` (counts such as ``--workers``, ``--num-tasks``, ``--seed``).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import numbers
import sys
from collections.abc import Iterator, Mapping

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


class OneLineArgumentParser(argparse.ArgumentParser):
    """argparse whose usage errors raise ValueError, so that ``user_errors`` reports them as one log line."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise ValueError(f"{self.prog}: {message} (see --help)")


def require_at_least(minimum: int, values: Mapping[str, object]) -> None:
    """ValueError naming the first flag whose value is not an integer >= ``minimum``.

    Used by the commands and by their Python functions alike, so ``convert(workers=0)`` is refused like
    ``--workers 0`` (and a string or float from a script is refused instead of failing deep inside).

    Args:
        minimum: The smallest valid value.
        values: ``{flag: value}``, e.g. ``{"--workers": 0}``.
    """
    for flag, value in values.items():
        if isinstance(value, bool) or not isinstance(value, numbers.Integral):
            raise ValueError(
                f"{flag} must be an integer >= {minimum}, got {value!r} ({type(value).__name__})"
            )
        if value < minimum:
            raise ValueError(f"{flag} must be >= {minimum}, got {value}")
