"""Open-loop action error of a trained SubgoalVLA on groups of a dataset's episodes.

Tells "fits its demonstrations but does not generalise" from "does not fit them": the policy predicts an
action chunk from every ``--every``-th recorded frame (the recorded image, state, history and instruction)
and the executed part of the chunk (its first ``n_action_steps`` actions) is compared with the expert's
recorded actions. A policy that reproduces the episodes it trained on but not new episodes of the same task
(other start states) has memorised its start states; one that misses both has not fit them. Closed-loop
success stays the measure of the policy; this only says where its errors begin.

    python benchmarks/study/open_loop_error.py --policy-path RUN/pretrained_model --dataset-root DATA \\
        --group trained=30-59 --group new=300-369 --every 5

Prints one row per group: episodes, frames, and the median and mean over frames of the Euclidean error of the
executed actions (dataset units, averaged over the chunk's steps), and of its first action alone. With
``--images-from-other-episode`` a second row per group feeds each frame the camera images of the same step of
another episode of the group (the objects elsewhere, everything else the frame's own): a policy that reads
where the objects are moves away from the expert, one that ignores them does not. With ``--instruction TEXT``
a row per group feeds every frame that instruction instead of its own (another task's, say): a policy that
tells tasks apart by their instruction moves away from the expert, one that infers the task from the scene
does not. ``--swap-camera KEY`` limits the image swap to one camera (which camera is read).
``--per-dimension`` adds under each row the mean absolute error of every action dimension.

Dimension legend: ``B`` frames in a batch, ``N`` executed steps of a chunk, ``A`` action dim.
"""

from __future__ import annotations

import logging
import statistics
import sys

import torch

from lerobot_subgoalvla.cli_errors import OneLineArgumentParser, user_errors
from lerobot_subgoalvla.contract.keys import ACTION_IS_PAD_KEY, ACTION_KEY, TASK_KEY
from lerobot_subgoalvla.visualization.checkpoint import load_policy

logger = logging.getLogger(__name__)


def parse_group(text: str) -> tuple[str, list[int]]:
    """``name=first-last`` (inclusive episode indices), or a comma-separated list of such spans and single
    episodes (``name=3-5,9,12-14``: a task's episodes scattered through play data) -> (name, episodes)."""
    name, _, spans = text.partition("=")
    episodes: list[int] = []
    for span in spans.split(","):
        first, dash, last = span.partition("-")
        last = last if dash else first
        if not (name and first.isdigit() and last.isdigit() and int(first) <= int(last)):
            raise ValueError(f"--group {text!r}: write NAME=FIRST-LAST or NAME=A-B,C,..., e.g. trained=30-59")
        episodes.extend(range(int(first), int(last) + 1))
    return name, episodes


def frame_indices(dataset, episodes: list[int], every: int) -> list[int]:
    """Every ``every``-th frame of each episode (dataset-wide indices)."""
    indices = []
    for episode in episodes:
        start = int(dataset.meta.episodes[episode]["dataset_from_index"])
        stop = int(dataset.meta.episodes[episode]["dataset_to_index"])
        indices.extend(range(start, stop, every))
    return indices


def other_episode_indices(dataset, episodes: list[int], every: int) -> list[int]:
    """For each frame of ``frame_indices``: the frame at the same step of the group's next episode (the last
    one's next is the first), or that episode's last frame where it is shorter."""
    donors = []
    for position, episode in enumerate(episodes):
        start = int(dataset.meta.episodes[episode]["dataset_from_index"])
        stop = int(dataset.meta.episodes[episode]["dataset_to_index"])
        other = episodes[(position + 1) % len(episodes)]
        other_start = int(dataset.meta.episodes[other]["dataset_from_index"])
        other_last = int(dataset.meta.episodes[other]["dataset_to_index"]) - 1
        donors.extend(min(other_start + step, other_last) for step in range(0, stop - start, every))
    return donors


class DecodedFrames:
    """A dataset's items by index, each decoded once: the variants of a group (own images, another episode's,
    another instruction) read the same frames, and the donors of ``--images-from-other-episode`` are frames
    of the group too, so one decode per frame serves every row. Holds one group's frames at a time (about
    1.9 GB for 284 Meta-World frames at 480 px)."""

    def __init__(self, dataset) -> None:
        self._dataset = dataset
        self._items: dict[int, dict] = {}

    def __getitem__(self, index: int) -> dict:
        if index not in self._items:
            self._items[index] = self._dataset[index]
        return self._items[index]


def _item(
    dataset, index: int, image_donor: int | None, camera_keys: list[str], instruction: str | None
) -> dict:
    item = dict(dataset[index])
    if image_donor is not None:
        donor = dataset[image_donor]
        item.update({key: donor[key] for key in camera_keys})
    if instruction is not None:
        item[TASK_KEY] = instruction
    return item


@torch.no_grad()
def executed_errors(
    policy,
    preprocessor,
    postprocessor,
    dataset,
    indices: list[int],
    batch_size: int,
    image_donors: list[int] | None = None,
    instruction: str | None = None,
    swapped_cameras: list[str] | None = None,
):
    """Per frame: (mean over the executed steps of |predicted - recorded action|, the first step's, and the
    mean over the executed steps of each action dimension's absolute error, an (A,) tensor).

    ``image_donors`` (one dataset index per frame) replaces each frame's camera images by the donor's, the
    rest of the input (state, history, instruction) kept: how far the error moves says how much the policy
    reads the image; ``swapped_cameras`` limits the swap to those cameras (default: all). ``instruction``
    replaces every frame's instruction the same way.
    """
    n_exec = policy.config.n_action_steps
    camera_keys = list(policy.config.image_features) if swapped_cameras is None else swapped_cameras
    donors = image_donors or [None] * len(indices)
    chunk_errors, first_errors, dimension_errors = [], [], []
    for start in range(0, len(indices), batch_size):
        span = slice(start, start + batch_size)
        items = [
            _item(dataset, i, d, camera_keys, instruction)
            for i, d in zip(indices[span], donors[span], strict=True)
        ]
        batch = torch.utils.data.default_collate(items)
        recorded = batch[ACTION_KEY][:, :n_exec]  # (B, N, A), dataset units
        valid = ~batch[ACTION_IS_PAD_KEY][:, :n_exec]  # (B, N)
        predicted = policy.predict_action_chunk(preprocessor(batch))[:, :n_exec]
        predicted = postprocessor(predicted).to(recorded.dtype)  # (B, N, A), dataset units
        distance = (predicted - recorded).norm(dim=-1)  # (B, N)
        chunk_errors += ((distance * valid).sum(1) / valid.sum(1)).tolist()
        first_errors += distance[:, 0].tolist()
        absolute = (predicted - recorded).abs() * valid.unsqueeze(-1)  # (B, N, A)
        dimension_errors += list(absolute.sum(1) / valid.sum(1, keepdim=True))
    return chunk_errors, first_errors, dimension_errors


def dimension_line(per_frame: list[torch.Tensor], names: list[str] | None) -> str:
    """``name mean`` for each action dimension: the mean over frames of its absolute error (a binary gripper
    command shows its wrong-sign steps here, which a median would hide)."""
    means = torch.stack(per_frame).mean(0).tolist()
    labels = names if isinstance(names, list) and len(names) == len(means) else range(len(means))
    return " ".join(f"{label} {value:.3f}" for label, value in zip(labels, means, strict=True))


def _parse_args(argv: list[str] | None):
    parser = OneLineArgumentParser(prog="open_loop_error.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy-path", required=True, help="a SubgoalVLA pretrained_model folder")
    parser.add_argument("--dataset-root", required=True, help="a LeRobotDataset with the policy's inputs")
    parser.add_argument("--repo-id", default="local/metaworld", help="the dataset's repo id")
    parser.add_argument(
        "--group", action="append", required=True, help="NAME=FIRST-LAST episodes, or NAME=A-B,C,... (repeat)"
    )
    parser.add_argument("--every", type=int, default=5, help="predict from every this-many-th frame")
    parser.add_argument("--batch-size", type=int, default=16, help="frames per forward pass")
    parser.add_argument("--seed", type=int, default=0, help="seeds the diffusion heads' noise")
    parser.add_argument(
        "--images-from-other-episode", action="store_true",
        help="also predict with each frame's images taken from the same step of the group's next episode "
        "(objects elsewhere, state and history kept): does the policy read where the objects are?",
    )  # fmt: skip
    parser.add_argument(
        "--instruction", default=None,
        help="also predict with this instruction in place of every frame's own (e.g. another task's): "
        "does the policy read which task it is given?",
    )  # fmt: skip
    parser.add_argument(
        "--swap-camera", action="append", default=None, metavar="KEY",
        help="with --images-from-other-episode, take only this camera from the other episode (repeat; "
        "default: every camera): which camera the policy reads an object from",
    )  # fmt: skip
    parser.add_argument(
        "--per-dimension", action="store_true",
        help="under each row, the mean absolute error of every action dimension (named as in the dataset): "
        "which part of the motion (a translation, a rotation, the gripper) carries the error",
    )  # fmt: skip
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    with user_errors(logger):
        args = _parse_args(argv)
        groups = [parse_group(text) for text in args.group]
        from lerobot.datasets import LeRobotDataset, LeRobotDatasetMetadata, resolve_delta_timestamps

        policy, preprocessor, postprocessor = load_policy(args.policy_path)
        policy.eval()
        if args.swap_camera and not args.images_from_other_episode:
            raise ValueError("--swap-camera picks cameras of --images-from-other-episode; add that flag")
        unknown = sorted(set(args.swap_camera or ()) - set(policy.config.image_features))
        if unknown:
            raise ValueError(
                f"--swap-camera {unknown[0]}: not a camera of the policy; use one of "
                f"{sorted(policy.config.image_features)}"
            )
        meta = LeRobotDatasetMetadata(args.repo_id, root=args.dataset_root)
        last = meta.total_episodes - 1
        for name, episodes in groups:
            if max(episodes) > last:
                raise ValueError(f"--group {name}: episode {max(episodes)} is past the last one ({last})")
        dataset = LeRobotDataset(
            args.repo_id,
            root=args.dataset_root,
            delta_timestamps=resolve_delta_timestamps(policy.config, meta),
            video_backend="pyav",
        )
        names = meta.features[ACTION_KEY].get("names")
        torch.manual_seed(args.seed)
        header = ("group", "input", "episodes", "frames", "median", "mean", "first med")
        print("{:<10} {:<8} {:>8} {:>7} {:>8} {:>8} {:>10}".format(*header))
        for name, episodes in groups:
            indices = frame_indices(dataset, episodes, args.every)
            variants = {"own": (None, None)}  # row label: (image donors, instruction)
            if args.images_from_other_episode:
                variants["other"] = (other_episode_indices(dataset, episodes, args.every), None)
            if args.instruction is not None:
                variants["instr"] = (None, args.instruction)
            frames = DecodedFrames(dataset) if len(variants) > 1 else dataset  # one row reads each frame once
            for images, (donors, instruction) in variants.items():
                chunk, first, per_dimension = executed_errors(
                    policy,
                    preprocessor,
                    postprocessor,
                    frames,
                    indices,
                    args.batch_size,
                    donors,
                    instruction,
                    args.swap_camera,
                )
                print(
                    f"{name:<10} {images:<8} {len(episodes):>8} {len(indices):>7} "
                    f"{statistics.median(chunk):>8.3f} {statistics.fmean(chunk):>8.3f} "
                    f"{statistics.median(first):>10.3f}"
                )
                if args.per_dimension:
                    print("    per dimension: " + dimension_line(per_dimension, names))
    return 0


if __name__ == "__main__":
    sys.exit(main())
