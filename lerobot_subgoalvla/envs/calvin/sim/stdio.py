"""Keep pybullet's C-level banners off the user's terminal.

pybullet prints from C straight to the process's file descriptors: ``pybullet build time`` (stderr) at import,
``argv[0]=`` (stdout) when a client connects, and the EGL plugin its device, GL vendor and teardown lines.
Python-level redirection cannot catch them, so ``quiet_c_output`` points fds 1 and 2 at /dev/null for the
duration of one pybullet call and restores them (an exception raised inside still reaches the user: Python
prints it after the block).
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator


@contextlib.contextmanager
def quiet_c_output() -> Iterator[None]:
    """Silence fds 1 and 2 inside the block."""
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:
            stream.flush()
    saved = [os.dup(1), os.dup(2)]
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 1)
            os.dup2(devnull.fileno(), 2)
        yield
    finally:
        for stream in (sys.stdout, sys.stderr):
            if stream is not None:
                stream.flush()
        for fd, copy in zip((1, 2), saved, strict=True):
            os.dup2(copy, fd)
            os.close(copy)
