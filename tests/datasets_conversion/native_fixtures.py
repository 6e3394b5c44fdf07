"""Tiny native CALVIN datasets built with our writer (used by the data tests and the benchmark)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lerobot_subgoalvla.datasets_conversion.calvin_format import (
    LanguageAnnotations,
    compute_statistics,
    write_frame,
    write_language,
    write_scene_info,
    write_segments,
    write_statistics,
)


def synthetic_frame(
    rng: np.random.Generator, frame_id: int, static: int, gripper: int
) -> dict[str, np.ndarray]:
    """One frame whose values encode its id (so tests can trace data back to the source)."""
    robot_obs = rng.normal(size=15)
    robot_obs[0] = frame_id  # traceable
    scene_obs = rng.normal(size=24)
    yy, xx = np.mgrid[0:static, 0:static]
    base = (xx * 3 + yy * 2 + frame_id * 5) % 256
    rgb_static = np.stack([base, (base + 80) % 256, (255 - base)], axis=-1).astype(np.uint8)
    yy, xx = np.mgrid[0:gripper, 0:gripper]
    rgb_gripper = np.stack([(xx * 4 + frame_id) % 256, (yy * 4) % 256, np.full_like(xx, 128)], -1).astype(
        np.uint8
    )
    return {
        "actions": rng.normal(size=7),
        "rel_actions": np.clip(rng.normal(size=7), -1, 1),
        "robot_obs": robot_obs,
        "scene_obs": scene_obs,
        "rgb_static": rgb_static,
        "rgb_gripper": rgb_gripper,
    }


def write_native_split(
    split_dir: Path,
    segments: Sequence[tuple[int, int]],
    windows: Sequence[tuple[int, int, str, str]] = (),
    scene_info: dict[str, tuple[int, int]] | None = None,
    static: int = 64,
    gripper: int = 64,
    seed: int = 0,
    stray_ids: Sequence[int] = (),
) -> Path:
    """Write a split: frames of every inclusive segment (+ stray frames), tables, annotations, statistics.

    Args:
        windows: (start, end, ann, task) language windows (end inclusive); none -> no annotation file.
    """
    rng = np.random.default_rng(seed)
    ids = [i for start, end in segments for i in range(start, end + 1)] + list(stray_ids)
    frames = {i: synthetic_frame(rng, i, static, gripper) for i in ids}
    for frame_id, arrays in frames.items():
        write_frame(split_dir, frame_id, arrays)
    write_segments(split_dir, np.array(segments))
    if scene_info is not None:
        write_scene_info(split_dir, scene_info)
    if windows:
        indx = np.array([(s, e) for s, e, _, _ in windows])
        write_language(split_dir, LanguageAnnotations(indx, [w[2] for w in windows], [w[3] for w in windows]))
    stack = {k: np.stack([f[k] for f in frames.values()]) for k in ("robot_obs", "scene_obs", "actions")}
    write_statistics(split_dir, compute_statistics(stack["robot_obs"], stack["scene_obs"], stack["actions"]))
    return split_dir
