"""One rule for every command that deletes or writes a folder: it never touches its own input.

``--overwrite`` deletes the output folder before writing it, and resumable commands remove their scratch
folders; an output that is the input, lies inside it or contains it would take the user's data with it. Every
such command calls :func:`refuse_overlap` before anything is deleted or written.
"""

from __future__ import annotations

from pathlib import Path


def refuse_overlap(output: Path, output_flag: str, source: Path, source_name: str) -> None:
    """ValueError if ``output`` is ``source``, inside it, or a folder that contains it.

    Args:
        output: The folder the command writes (and may delete).
        output_flag: Its flag, for the message (e.g. ``--root``).
        source: The input the command reads.
        source_name: How the message names the input (e.g. ``the CALVIN folder``).
    """
    out, src = Path(output).resolve(), Path(source).resolve()
    if out == src or src in out.parents or out in src.parents:
        relation = "is" if out == src else ("is inside" if src in out.parents else "contains")
        raise ValueError(
            f"{output_flag} {output} {relation} {source_name} {source}: writing there would delete or mix "
            f"with the input; choose an {output_flag} outside {src}"
        )
