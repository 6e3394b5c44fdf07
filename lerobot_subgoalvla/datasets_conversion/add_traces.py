"""``subgoalvla-add-traces``: give any LeRobotDataset the state history and subgoal traces SubgoalVLA uses.

::

    subgoalvla-add-traces --repo-id me/my_robot --root ~/data/my_robot --output-root ~/data/my_robot_traces
    lerobot-train --policy.type=subgoalvla --dataset.repo_id=me/my_robot --dataset.root=~/data/my_robot_traces

Reads the dataset (local with ``--root``, else from the Hub cache, downloading when online), computes for
every frame ``observation.state_history`` (h, p) and ``observation.subgoal_trace`` (M, p) as windows over its
episode's ``observation.state`` (``contract.window``), and writes a copy with the two columns to
``--output-root``; videos and images are copied unchanged, the input is never modified. The window defaults to
the paper's carried to the dataset's fps (``TraceWindow.for_fps``: same seconds, same number of states);
``--history-length``, ``--trace-length``, ``--trace-start`` and ``--stride`` set it by hand. The window, the
fps, the wrapping angles (``--angle-dims``/``--angle-home``, none by default) and any extra instructions for
the vocabulary (``--instructions``) are recorded in the trace feature's metadata (``contract.metadata``),
where the policy reads them when ``lerobot-train`` builds it.

The copy is written to ``OUTPUT_ROOT.partial`` and renamed when complete, so an interrupted run leaves no
half-written dataset (rerun the same command; a stale ``.partial`` is replaced). LeRobot's own
``lerobot.datasets.add_features`` does the copying.
"""

from __future__ import annotations

import argparse
import logging
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lerobot_subgoalvla.cli_errors import OneLineArgumentParser, user_errors
from lerobot_subgoalvla.contract.keys import STATE_HISTORY_KEY, STATE_KEY, SUBGOAL_TRACE_KEY, TRACE_COLUMNS
from lerobot_subgoalvla.contract.metadata import ProprioMetadata
from lerobot_subgoalvla.contract.window import PAPER_HISTORY_LENGTH, PAPER_TRACE_LENGTH, TraceWindow

logger = logging.getLogger(__name__)
COMMAND = "subgoalvla-add-traces"


def choose_window(
    fps: float,
    history_length: int = PAPER_HISTORY_LENGTH,
    trace_length: int = PAPER_TRACE_LENGTH,
    trace_start: int | None = None,
    stride: int | None = None,
) -> TraceWindow:
    """The window for a dataset at ``fps``: the fps-scaled paper window, with any value given by hand."""
    scaled = TraceWindow.for_fps(fps, history_length, trace_length)
    return TraceWindow(
        history_length,
        scaled.trace_start if trace_start is None else trace_start,
        trace_length,
        scaled.stride if stride is None else stride,
    )


def episode_states(root: Path, state_dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Every frame's state and episode index in the dataset's row order (its sorted data files).

    Returns:
        states (F, p) float32 and episode indices (F,) int64, F = frames in the dataset.
    """
    import pandas as pd

    files = sorted((root / "data").glob("*/*.parquet"))
    if not files:
        raise ValueError(f"{root}: no data files under data/; is it a LeRobotDataset v3?")
    frames = pd.concat(
        [pd.read_parquet(path, columns=[STATE_KEY, "episode_index", "frame_index"]) for path in files],
        ignore_index=True,
    )
    states = np.stack(frames[STATE_KEY].to_numpy()).astype(np.float32).reshape(len(frames), state_dim)
    return states, frames["episode_index"].to_numpy(dtype=np.int64)


def window_columns(
    states: np.ndarray, episodes: np.ndarray, window: TraceWindow
) -> tuple[np.ndarray, np.ndarray]:
    """History (F, h, p) and trace (F, M, p) of every frame, each episode's windows over its own states.

    Raises:
        ValueError: an episode whose frames are not contiguous, or one shorter than the trace window.
    """
    starts = np.flatnonzero(np.r_[True, episodes[1:] != episodes[:-1]])
    ends = np.r_[starts[1:], len(episodes)]
    if len(set(episodes[starts].tolist())) != len(starts):
        raise ValueError("the dataset's frames of one episode are not contiguous; it cannot be windowed")
    lengths = ends - starts
    shortest = int(np.argmin(lengths))
    if lengths[shortest] <= window.trace_end:
        raise ValueError(
            f"episode {int(episodes[starts[shortest]])} has {int(lengths[shortest])} frames but the trace "
            f"window reaches {window.trace_end} frames ahead ({window.describe()}); lower --trace-start, "
            "--stride "
            "or --trace-length"
        )
    histories = np.concatenate([window.histories(states[a:b]) for a, b in zip(starts, ends, strict=True)])
    traces = np.concatenate([window.traces(states[a:b]) for a, b in zip(starts, ends, strict=True)])
    return histories, traces


def add_traces(
    repo_id: str,
    root: Path | None,
    output_root: Path,
    output_repo_id: str | None = None,
    window_overrides: dict[str, int | None] | None = None,
    angle_dims: Sequence[int] = (),
    angle_home: Sequence[float] = (),
    instructions: Sequence[str] = (),
) -> Any:
    """Write ``repo_id`` (at ``root``) with history and trace columns to ``output_root`` (module docstring).

    Returns:
        The new ``LeRobotDataset``.
    """
    from lerobot.datasets import LeRobotDataset, add_features

    output_root = Path(output_root).expanduser()
    if root is not None and Path(root).expanduser().resolve() == output_root.resolve():
        raise ValueError("--output-root must differ from --root: the input dataset is never changed")
    if output_root.exists():
        raise FileExistsError(f"--output-root {output_root} already exists; choose a new folder")
    dataset = LeRobotDataset(repo_id, root=root, video_backend="pyav")  # no torchcodec probe (needs FFmpeg)
    features = dataset.meta.features
    _check_input(features, dataset.root)
    state_dim = tuple(features[STATE_KEY]["shape"])[-1]
    window = choose_window(dataset.meta.fps, **(window_overrides or {}))
    metadata = ProprioMetadata(
        window, dataset.meta.fps, tuple(angle_dims), tuple(angle_home), tuple(instructions), COMMAND
    )
    metadata.check_state_dim(state_dim, "--angle-dims")
    states, episodes = episode_states(dataset.root, state_dim)
    histories, traces = window_columns(states, episodes, window)
    new_features = metadata.attach(
        {
            SUBGOAL_TRACE_KEY: {"dtype": "float32", "shape": traces.shape[1:], "names": None},
        }
    )
    new_features[STATE_HISTORY_KEY] = {"dtype": "float32", "shape": histories.shape[1:], "names": None}
    partial = output_root.with_name(output_root.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)  # a previous interrupted run's leftovers
    add_features(
        dataset,
        {
            key: (values, new_features[key])
            for key, values in ((STATE_HISTORY_KEY, histories), (SUBGOAL_TRACE_KEY, traces))
        },
        output_dir=partial,
        repo_id=output_repo_id or repo_id,
    )
    partial.rename(output_root)
    logger.info(
        "%s: %d episodes, %d frames with history and trace (%s at %g fps) -> %s",
        repo_id, dataset.meta.total_episodes, len(states), window.describe(), dataset.meta.fps, output_root,
    )  # fmt: skip
    return LeRobotDataset(output_repo_id or repo_id, root=output_root, video_backend="pyav")


def _check_input(features: dict[str, dict], root: Path) -> None:
    """One line naming every contract problem of the input dataset."""
    present = [key for key in TRACE_COLUMNS if key in features]
    if present:
        raise ValueError(
            f"{root} already has {present}; SubgoalVLA trains on it as it is (to cut another window, start "
            "from the dataset without them)"
        )
    missing = [] if STATE_KEY in features else [STATE_KEY]
    if not any(feature.get("dtype") in ("image", "video") for feature in features.values()):
        missing.append("a camera (an image or video feature)")
    if missing:
        raise ValueError(f"{root} lacks {' and '.join(missing)}, which SubgoalVLA needs; it cannot be used")
    if len(features[STATE_KEY]["shape"]) != 1:
        raise ValueError(
            f"{root}: {STATE_KEY} has shape {features[STATE_KEY]['shape']}; a vector (p,) is needed"
        )


def _int_list(text: str) -> list[int]:
    return [int(part) for part in text.split(",") if part.strip()]


def _float_list(text: str) -> list[float]:
    return [float(part) for part in text.split(",") if part.strip()]


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The CLI flags (module docstring)."""
    parser = OneLineArgumentParser(
        prog=COMMAND, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repo-id", required=True, help="the input dataset's id, e.g. lerobot/pusht")
    parser.add_argument("--root", type=Path, default=None, help="its local folder (default: the Hub cache)")
    parser.add_argument("--output-root", type=Path, required=True, help="a new folder for the copy")
    parser.add_argument("--output-repo-id", default=None, help="the copy's id (default: --repo-id)")
    parser.add_argument("--history-length", type=int, default=PAPER_HISTORY_LENGTH, help="h, history states")
    parser.add_argument("--trace-length", type=int, default=PAPER_TRACE_LENGTH, help="M, trace states")
    parser.add_argument("--trace-start", type=int, default=None, help="frames to the first trace state")
    parser.add_argument("--stride", type=int, default=None, help="frames between window states")
    parser.add_argument(
        "--angle-dims", type=_int_list, default=[], help="wrapping angles in the state: 3,4,5"
    )
    parser.add_argument("--angle-home", type=_float_list, default=[], help="their home angles: 3.14159,0,0")
    parser.add_argument(
        "--instruction", action="append", default=[], help="an extra instruction for the vocabulary (repeat)"
    )
    parser.add_argument("--push-to-hub", action="store_true", help="upload the copy (needs network + login)")
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> None:
    """Entry point of ``subgoalvla-add-traces``: one log line per error, non-zero exit."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger().setLevel(logging.INFO)
    with user_errors(logger, "interrupted; rerun the same command (nothing was written to --output-root)"):
        args = parse_args(argv)
        if len(args.angle_dims) != len(args.angle_home):
            raise ValueError(
                f"--angle-home needs one value per --angle-dims entry ({len(args.angle_dims)}), "
                f"got {len(args.angle_home)}"
            )
        overrides = {
            "history_length": args.history_length,
            "trace_length": args.trace_length,
            "trace_start": args.trace_start,
            "stride": args.stride,
        }
        dataset = add_traces(
            args.repo_id, args.root, args.output_root, args.output_repo_id, overrides,
            args.angle_dims, args.angle_home, args.instruction,
        )  # fmt: skip
        if args.push_to_hub:
            dataset.push_to_hub(tags=["SubgoalVLA", "subgoal-traces"])


if __name__ == "__main__":
    main()
