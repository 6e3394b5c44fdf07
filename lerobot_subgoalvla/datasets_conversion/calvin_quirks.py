"""CALVIN dataset quirks and how the converter resolves them (docs/calvin.md 1.5, 1.7, 1.8).

Decisions (documented in docs/data.md):

* **Block slot order.** ``scene_obs[6:24]`` holds the three blocks in the scene config's ``movable_objects``
  order: A = pink, blue, red; B, D = red, blue, pink; C = blue, red, pink (spec 1.5). The converter
  *canonicalises* every frame to red, blue, pink (the evaluation scene D's order,
  ``calvin_vocab.BLOCK_COLORS``) so that ``observation.environment_state`` means the same thing in every
  scene, and records the choice in the trace feature's metadata (``block_order``).
* **Language windows.** ``info.indx`` ends are inclusive (spec 1.7). A window belongs to the segment
  (row of ``ep_start_end_ids``) containing its start; an end beyond that segment is clamped to the segment's
  last frame (windows never cross rows, spec 1.2). A window whose start lies in no segment (stray ids) or
  whose end precedes its start is dropped. Overlapping windows are kept as separate episodes (a frame may
  appear in several, as in CALVIN's own loaders).
* **ALL mode tasks.** One episode per segment; each frame's task is the annotation of the covering window
  with the latest start (overlaps resolve to the most recent instruction), else :data:`PLAY_TASK`.

Dimension legend:
    N   segments or windows
    F   frames
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from lerobot_subgoalvla.calvin_vocab import BLOCK_COLORS
from lerobot_subgoalvla.datasets_conversion.calvin_format import LanguageAnnotations

logger = logging.getLogger(__name__)

#: Block slot order of each scene (spec 1.5; calvin_env scene configs). "procedural" is our generated scene,
#: whose simulation lists the blocks in CALVIN's canonical order.
SCENE_BLOCK_ORDER: Mapping[str, tuple[str, ...]] = {
    "calvin_scene_A": ("pink", "blue", "red"),
    "calvin_scene_B": ("red", "blue", "pink"),
    "calvin_scene_C": ("blue", "red", "pink"),
    "calvin_scene_D": ("red", "blue", "pink"),
    "procedural": ("red", "blue", "pink"),
}
CANONICAL_BLOCK_ORDER: tuple[str, ...] = BLOCK_COLORS
#: Task string of ALL-mode frames that no language window covers.
PLAY_TASK = "play freely in the CALVIN scene"
_SLOT_START, _SLOT_SIZE = 6, 6


def block_order_of(scene: str) -> tuple[str, ...]:
    """Slot order of ``scene``; raises naming the known scenes."""
    if scene not in SCENE_BLOCK_ORDER:
        raise ValueError(
            f"unknown scene {scene!r} in scene_info.npy; known scenes: {', '.join(SCENE_BLOCK_ORDER)} "
            "(rename the scene or add its block order to calvin_quirks.SCENE_BLOCK_ORDER)"
        )
    return SCENE_BLOCK_ORDER[scene]


def canonicalize_scene_obs(scene_obs: np.ndarray, block_order: tuple[str, ...]) -> np.ndarray:
    """Reorder the block slots of ``scene_obs`` (F, 24) from ``block_order`` to red, blue, pink.

    Returns:
        (F, 24) copy; dims 0-5 (doors, button, switch, lights) are unchanged.
    """
    out = np.array(scene_obs, copy=True)
    for target_slot, color in enumerate(CANONICAL_BLOCK_ORDER):
        source_slot = block_order.index(color)
        src = slice(_SLOT_START + _SLOT_SIZE * source_slot, _SLOT_START + _SLOT_SIZE * (source_slot + 1))
        dst = slice(_SLOT_START + _SLOT_SIZE * target_slot, _SLOT_START + _SLOT_SIZE * (target_slot + 1))
        out[..., dst] = scene_obs[..., src]
    return out


@dataclass(frozen=True)
class EpisodeSpec:
    """One output episode: inclusive source frame range and its task per frame.

    Attributes:
        segment: row of ``ep_start_end_ids`` the episode lies in.
        start: first source frame id.
        end: last source frame id (inclusive).
        tasks: one task string per frame (length ``end - start + 1``).
    """

    segment: int
    start: int
    end: int
    tasks: tuple[str, ...]

    @property
    def length(self) -> int:
        """Number of frames."""
        return self.end - self.start + 1


@dataclass(frozen=True)
class WindowReport:
    """What happened to the annotation windows (logged and written to the dataset card)."""

    kept: int = 0
    clamped: int = 0
    dropped_stray: int = 0
    dropped_invalid: int = 0


def _segment_of(segments: np.ndarray, frame_id: int) -> int | None:
    rows = np.nonzero((segments[:, 0] <= frame_id) & (frame_id <= segments[:, 1]))[0]
    return int(rows[0]) if len(rows) else None


def language_episodes(
    segments: np.ndarray, annotations: LanguageAnnotations
) -> tuple[list[EpisodeSpec], WindowReport]:
    """LANG mode: one episode per annotation window, clamped to its segment (module docstring)."""
    episodes: list[EpisodeSpec] = []
    clamped = stray = invalid = 0
    for (start, end), text in zip(annotations.indx.tolist(), annotations.ann, strict=True):
        if end < start:
            invalid += 1
            continue
        segment = _segment_of(segments, start)
        if segment is None:
            stray += 1
            continue
        segment_end = int(segments[segment, 1])
        if end > segment_end:
            clamped += 1
            end = segment_end
        episodes.append(EpisodeSpec(segment, int(start), int(end), (text,) * (end - start + 1)))
    report = WindowReport(len(episodes), clamped, stray, invalid)
    if clamped or stray or invalid:
        logger.warning(
            "language windows: %d kept, %d clamped to their segment end, %d dropped (start in no segment), "
            "%d dropped (end < start)",
            report.kept,
            clamped,
            stray,
            invalid,
        )
    return episodes, report


def play_episodes(segments: np.ndarray, annotations: LanguageAnnotations | None) -> list[EpisodeSpec]:
    """ALL mode: one episode per segment, per-frame task from the latest-starting covering window."""
    episodes = []
    windows = (
        [] if annotations is None else sorted(zip(annotations.indx.tolist(), annotations.ann, strict=True))
    )
    for row, (start, end) in enumerate(segments.tolist()):
        tasks = [PLAY_TASK] * (end - start + 1)
        for (w_start, w_end), text in windows:  # sorted by start: later windows overwrite earlier ones
            lo, hi = max(w_start, start), min(w_end, end)
            if w_start >= start and lo <= hi:
                tasks[lo - start : hi - start + 1] = [text] * (hi - lo + 1)
        episodes.append(EpisodeSpec(row, int(start), int(end), tuple(tasks)))
    return episodes
