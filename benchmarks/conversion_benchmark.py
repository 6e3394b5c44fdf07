"""Conversion throughput beside the codec floor, measured side by side in one run.

The converter's per-frame work is: read + decompress the npz, compute history/trace, hand the frame to
LeRobot's writer, which encodes both cameras with AV1 (libsvtav1 via PyAV, LeRobot's default encoder
settings) and writes parquet. The *codec floor* is PyAV alone encoding the very same frames, one mp4 per
episode and camera, with the same ``RGBEncoderConfig`` options: no conversion can be faster per worker.

Usage::

    HF_HUB_OFFLINE=1 python benchmarks/conversion_benchmark.py --episodes 8 --frames-per-episode 64 --repeats
    2

A second reference is LeRobot's writer alone (``create -> add_frame -> save_episode -> finalize`` with
streaming AV1 encoding, the converter's settings) fed with arrays already in memory: the best any converter
built on LeRobot's public writer can do per process. The table lists wall time (median of ``--repeats``),
frames/s, frames/s per worker, the ratio to the floor per worker (target >= 80 %) and the extrapolated time
for task_ABC_D's LANG training split (~1.07 M frames: 17,870 windows, spec 1.7) at that rate. Source frames
are CALVIN-sized (200x200 static, 84x84 gripper) with a textured, moving image content (not flat colour) so
that the encoder does real work.
"""

from __future__ import annotations

import argparse
import logging
import os
import statistics
import tempfile
import time
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

from lerobot_subgoalvla.contract.calvin import GRIPPER_CAMERA_KEY as GRIPPER
from lerobot_subgoalvla.contract.calvin import STATIC_CAMERA_KEY as STATIC
from lerobot_subgoalvla.datasets_conversion.calvin_format import (
    LanguageAnnotations,
    write_frame,
    write_language,
    write_segments,
)
from lerobot_subgoalvla.datasets_conversion.convert_calvin import convert
from lerobot_subgoalvla.datasets_conversion.lerobot_parts import ConversionOptions
from lerobot_subgoalvla.datasets_conversion.video_frames import encoder_options

logger = logging.getLogger("conversion_benchmark")
ABC_D_LANG_FRAMES = 1_070_000


def _texture(rng: np.random.Generator, size: int) -> np.ndarray:
    coarse = rng.integers(0, 256, size=(size // 8 + 2, size // 8 + 2, 3)).astype(np.float32)
    return np.kron(coarse, np.ones((8, 8, 1), dtype=np.float32))  # blocky texture, larger than the frame


def _frames(num: int, size: int, rng: np.random.Generator) -> np.ndarray:
    texture = _texture(rng, size)
    out = np.empty((num, size, size, 3), dtype=np.uint8)  # (F, H, W, 3)
    for t in range(num):
        shift = t % 8
        frame = texture[shift : shift + size, shift : shift + size] + rng.normal(0, 4, size=(size, size, 3))
        out[t] = np.clip(frame, 0, 255).astype(np.uint8)
    return out


def build_source(root: Path, episodes: int, length: int) -> dict[str, np.ndarray]:
    """A native split of ``episodes`` segments with one full-length language window each."""
    rng = np.random.default_rng(0)
    split_dir = root / "training"
    static, gripper = _frames(episodes * length, 200, rng), _frames(episodes * length, 84, rng)
    for i in range(episodes * length):
        write_frame(
            split_dir,
            i,
            {
                "actions": rng.normal(size=7),
                "rel_actions": rng.uniform(-1, 1, 7),
                "robot_obs": rng.normal(size=15),
                "scene_obs": rng.normal(size=24),
                "rgb_static": static[i],
                "rgb_gripper": gripper[i],
            },
        )
    rows = np.array([(e * length, e * length + length - 1) for e in range(episodes)])
    write_segments(split_dir, rows)
    write_language(
        split_dir, LanguageAnnotations(rows, ["open the drawer"] * episodes, ["open_drawer"] * episodes)
    )
    return {"static": static, "gripper": gripper}


def codec_floor(frames: dict[str, np.ndarray], episodes: int, length: int, out_dir: Path) -> float:
    """Seconds for PyAV to encode every episode of both cameras with LeRobot's default AV1 settings."""
    from lerobot.configs.video import RGBEncoderConfig

    encoder = RGBEncoderConfig()
    options = encoder.get_codec_options(None, as_strings=True)
    start = time.perf_counter()
    for episode in range(episodes):
        for camera, video in frames.items():
            with av.open(str(out_dir / f"{camera}-{episode}.mp4"), "w") as container:
                stream = container.add_stream(encoder.vcodec, 30, options=options)
                stream.pix_fmt, stream.width, stream.height = encoder.pix_fmt, video.shape[2], video.shape[1]
                stream.time_base = Fraction(1, 30)
                for t in range(episode * length, (episode + 1) * length):
                    frame = av.VideoFrame.from_ndarray(video[t], format="rgb24")
                    frame.pts = t - episode * length
                    container.mux(stream.encode(frame))
                container.mux(stream.encode())
    return time.perf_counter() - start


def writer_alone(src: Path, out_dir: Path) -> float:
    """Seconds for LeRobot's writer alone (same settings as the converter) fed with arrays already in
    memory."""
    from lerobot.datasets import LeRobotDataset

    from lerobot_subgoalvla.datasets_conversion.calvin_format import CalvinSplit
    from lerobot_subgoalvla.datasets_conversion.calvin_quirks import language_episodes
    from lerobot_subgoalvla.datasets_conversion.lerobot_parts import (
        build_features,
        episode_arrays,
        iter_frames,
    )

    split, options = CalvinSplit(src / "training"), ConversionOptions()
    episodes, _ = language_episodes(split.segments, split.language())
    arrays = [episode_arrays(split, episode, options) for episode in episodes]
    features = build_features(arrays[0][STATIC].shape[1:], arrays[0][GRIPPER].shape[1:], options)
    start = time.perf_counter()
    dataset = LeRobotDataset.create(
        "bench/writer",
        30,
        features,
        root=out_dir,
        use_videos=True,
        video_backend="pyav",
        **encoder_options(True, max(len(episode[STATIC]) for episode in arrays)),
    )
    for episode in arrays:
        for frame in iter_frames(episode):
            dataset.add_frame(frame)
        dataset.save_episode()
    dataset.finalize()
    return time.perf_counter() - start


def main() -> None:
    """Run the measurements and log the table."""
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    logging.getLogger().setLevel(logging.INFO)
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--frames-per-episode", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    num_frames = args.episodes * args.frames_per_episode
    with tempfile.TemporaryDirectory() as tmp:
        tmp_dir = Path(tmp)
        frames = build_source(tmp_dir / "src", args.episodes, args.frames_per_episode)
        rows: list[tuple[str, int, float]] = []
        for repeat in range(args.repeats):
            floor_dir = tmp_dir / f"floor{repeat}"
            floor_dir.mkdir()
            rows.append(
                (
                    "codec floor (PyAV AV1 alone)",
                    1,
                    codec_floor(frames, args.episodes, args.frames_per_episode, floor_dir),
                )
            )
            rows.append(
                (
                    "LeRobot writer alone (arrays in memory)",
                    1,
                    writer_alone(tmp_dir / "src", tmp_dir / f"w{repeat}"),
                )
            )
            for workers in args.workers:
                start = time.perf_counter()
                convert(
                    tmp_dir / "src",
                    "bench/calvin",
                    tmp_dir / f"out{repeat}-{workers}",
                    options=ConversionOptions(),
                    workers=workers,
                    episodes_per_part=max(1, args.episodes // (2 * workers)),
                )
                rows.append(
                    (f"convert LANG, video, {workers} worker(s)", workers, time.perf_counter() - start)
                )
    floor_fps = num_frames / statistics.median(s for name, _, s in rows if name.startswith("codec"))
    load = os.getloadavg()[0]
    lines = [
        f"{num_frames} frames (200x200 + 84x84 per frame), median of {args.repeats}, load average {load:.1f}",
        "| run | workers | wall s | frames/s | frames/s/worker | % of floor per worker | est. ABC_D LANG "
        "(1.07 M) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name in dict.fromkeys(name for name, _, _ in rows):
        workers = next(w for n, w, _ in rows if n == name)
        wall = statistics.median(s for n, _, s in rows if n == name)
        fps = num_frames / wall
        hours = ABC_D_LANG_FRAMES / fps / 3600
        lines.append(
            f"| {name} | {workers} | {wall:.1f} | {fps:.1f} | {fps / workers:.1f} | "
            f"{100 * fps / workers / floor_fps:.0f} % | {hours:.1f} h |"
        )
    logger.info("\n".join(lines))


if __name__ == "__main__":
    main()
