"""The checks on where a command reads and writes, made before anything is read, deleted or written.

``--overwrite`` deletes the output folder before writing it, and resumable commands remove their scratch
folders; an output that is the input, lies inside it or contains it would take the user's data with it. Every
such command calls :func:`refuse_overlap`. A dataset id names a folder too (the default output is
``$HF_LEROBOT_HOME/ID``): an empty id or one like ``/x`` or ``a/..`` would point that folder, and
``--overwrite``, at ``$HF_LEROBOT_HOME`` itself or outside it, so :func:`check_repo_id` refuses any id the
Hub would refuse.
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


def check_repo_id(repo_id: str, flag: str = "--repo-id") -> None:
    """ValueError unless ``repo_id`` is a valid Hub id (``NAME`` or ``NAMESPACE/NAME``)."""
    from huggingface_hub.errors import HFValidationError
    from huggingface_hub.utils import validate_repo_id

    try:
        validate_repo_id(repo_id)
    except HFValidationError as error:
        reason = str(error).split(":")[0].split(". Use")[0]
        raise ValueError(
            f"{flag} {repo_id!r} is not a dataset id ({reason}); use NAMESPACE/NAME, e.g. me/calvin_abc_lang"
        ) from None


def check_source_folder(source: Path, name: str, what: str) -> None:
    """FileNotFoundError / NotADirectoryError unless ``source`` is an existing folder.

    Args:
        source: The input folder.
        name: How the message names it (``SRC``).
        what: What it must be, for the fix (``a CALVIN dataset folder ...``).
    """
    if not source.exists():
        raise FileNotFoundError(f"{name} {source}: not found; point {name} at {what}")
    if not source.is_dir():
        raise NotADirectoryError(f"{name} {source}: is a file, not a folder; point {name} at {what}")
