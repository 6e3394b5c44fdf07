"""Up-front validation of a native CALVIN split (docs/calvin.md 1.1-1.3, 1.7).

Every problem is reported as ONE line naming the file and the fix (team standard), raised as
``FileNotFoundError`` (something missing) or ``ValueError`` (something malformed). The check is cheap so
that a multi-hour conversion fails in seconds: metadata files are parsed, every frame id covered by
``ep_start_end_ids.npy`` must exist (a directory listing, no decompression), and the first and last frame
of every segment are opened and checked key by key against ``NPZ_SCHEMA``. Frames in between are checked
when the converter reads them (``calvin_format.check_frame``), with the same messages.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lerobot_subgoalvla.datasets_conversion.calvin_format import (
    CORE_KEYS,
    EPISODE_IDS_FILE,
    LANG_ANN_FILE,
    SCENE_INFO_FILE,
    CalvinSplit,
    check_frame,
    frame_filename,
)

logger = logging.getLogger(__name__)

_FRAME_RE = re.compile(r"^episode_(\d{7})\.npz$")


def _load_split(split_dir: Path) -> CalvinSplit:
    if not split_dir.is_dir():
        raise FileNotFoundError(
            f"{split_dir}: split folder not found; point SRC at a CALVIN dataset folder containing "
            "training/ and/or validation/ (e.g. task_ABC_D)"
        )
    ids_path = split_dir / EPISODE_IDS_FILE
    if not ids_path.is_file():
        raise FileNotFoundError(
            f"{ids_path}: segment table missing; copy ep_start_end_ids.npy from the release"
        )
    try:
        split = CalvinSplit(split_dir)
    except (ValueError, OSError, EOFError) as error:
        raise ValueError(
            f"{split_dir}: unreadable {EPISODE_IDS_FILE} or {SCENE_INFO_FILE} ({error}); re-download them"
        ) from error
    if len(split.segments) == 0:
        raise ValueError(f"{ids_path}: empty split (no segments); use a split with recorded frames")
    _check_segment_table(ids_path, split.segments)
    return split


def _check_segment_table(ids_path: Path, segments: np.ndarray) -> None:
    """Refuse tables that would convert into wrong data rather than fail: CalvinSplit casts to int64, so
    float ids would be truncated silently, and overlapping rows would put the same frames in two episodes.
    Rows out of order are fine (episodes follow the table's order)."""
    dtype = np.load(ids_path, mmap_mode="r").dtype
    if not np.issubdtype(dtype, np.integer):
        raise ValueError(
            f"{ids_path}: holds {dtype} values; frame ids must be integers - re-download the file"
        )
    lengths = segments[:, 1] - segments[:, 0] + 1
    if (lengths < 1).any():
        row = int(np.argmin(lengths))
        raise ValueError(f"{ids_path}: row {row} {segments[row].tolist()} has end < start; fix the table")
    if (segments < 0).any():
        row = int(np.argmin(segments.min(axis=1)))
        raise ValueError(
            f"{ids_path}: row {row} {segments[row].tolist()} has a negative frame id; fix the table"
        )
    order = np.argsort(segments[:, 0], kind="stable")
    clash = np.nonzero(segments[order[1:], 0] <= segments[order[:-1], 1])[0]
    if len(clash):
        a, b = sorted(int(i) for i in order[[clash[0], clash[0] + 1]])
        raise ValueError(
            f"{ids_path}: rows {a} {segments[a].tolist()} and {b} {segments[b].tolist()} overlap; a frame "
            "belongs to one segment only - fix the table"
        )


def _check_coverage(split: CalvinSplit) -> None:
    present = {int(m.group(1)) for name in os.listdir(split.root) if (m := _FRAME_RE.match(name))}
    if not present:
        raise ValueError(
            f"{split.root}: empty split (no episode_XXXXXXX.npz files); extract the frame files here"
        )
    for start, end in split.segments.tolist():
        missing = next((i for i in range(start, end + 1) if i not in present), None)
        if missing is not None:
            raise FileNotFoundError(
                f"{split.root / frame_filename(missing)}: frame file missing although {EPISODE_IDS_FILE} "
                "covers "
                f"it (segment [{start}, {end}]); restore the file or fix the segment table"
            )
    for start, _ in split.segments.tolist():
        split.scene_of(start)  # raises when scene_info.npy does not cover the segment
    covered = split.num_frames
    if len(present) > covered:
        logger.info(
            "%s: %d frame files outside any segment are ignored (stray ids)",
            split.root,
            len(present) - covered,
        )


def _check_language(split: CalvinSplit) -> None:
    path = split.root / LANG_ANN_FILE
    try:
        annotations = split.language()
    except FileNotFoundError:
        raise
    except (KeyError, ValueError, OSError, EOFError, AttributeError) as error:
        raise ValueError(
            f"{path}: malformed language annotations ({error!r}); expected CALVIN's nested dict with "
            "info.indx, language.ann and language.task - re-download the file"
        ) from error
    if len(annotations) == 0:
        raise ValueError(f"{path}: no annotation windows; LANG mode needs windows - use --mode all")


def validate_split(split_dir: Path, require_language: bool, keys: Sequence[str] = CORE_KEYS) -> CalvinSplit:
    """Check a native split before converting it.

    Args:
        split_dir: ``.../training`` or ``.../validation``.
        require_language: LANG mode needs ``lang_annotations/auto_lang_ann.npy``.
        keys: npz keys that must be present with the right shape/dtype (the converter's ``CORE_KEYS``;
            pass ``calvin_format.ALL_KEYS`` to require the full 10-key native profile).

    Returns:
        The opened split.
    """
    split = _load_split(Path(split_dir))
    _check_coverage(split)
    if require_language:
        _check_language(split)
    image_shapes: dict[str, tuple[int, ...]] = {}
    for start, end in split.segments.tolist():
        for frame_id in sorted({start, end}):
            arrays = check_frame(split.frame_path(frame_id), keys)
            for key in ("rgb_static", "rgb_gripper"):
                if key in arrays and image_shapes.setdefault(key, arrays[key].shape) != arrays[key].shape:
                    raise ValueError(
                        f"{split.frame_path(frame_id)}: {key} has shape {arrays[key].shape} but earlier "
                        "frames "
                        f"have {image_shapes[key]}; all frames of a split need one camera size"
                    )
    return split
