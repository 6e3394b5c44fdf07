"""Files that are never half-written: write to a temporary file beside the target, then rename it into place.

Every file the project writes for the user (frames, index files, chain lists, results, reports) goes through
here, so an interrupted command leaves either the old file or the new one, and the new one has the permissions
a plain ``open()`` would give it (``mkstemp`` alone makes 0600 files that other users cannot read).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO


def atomic_write(path: str | Path, data: str | bytes | Callable[[BinaryIO], object]) -> None:
    """Write ``data`` (text, bytes, or a function that writes into a binary file object) to ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            if callable(data):
                data(handle)
            else:
                handle.write(data.encode() if isinstance(data, str) else data)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
