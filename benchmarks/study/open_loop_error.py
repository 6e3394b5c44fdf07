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
executed actions (dataset units, averaged over the chunk's steps), and of its first action alone.

Dimension legend: ``B`` frames in a batch, ``N`` executed steps of a chunk, ``A`` action dim.
"""

from __future__ import annotations

import logging
import statistics
import sys

import torch

from lerobot_subgoalvla.cli_errors import OneLineArgumentParser, user_errors
from lerobot_subgoalvla.contract.keys import ACTION_IS_PAD_KEY, ACTION_KEY
from lerobot_subgoalvla.visualization.checkpoint import load_policy

logger = logging.getLogger(__name__)


def parse_group(text: str) -> tuple[str, list[int]]:
    """``name=first-last`` (inclusive episode indices) -> (name, episodes)."""
    name, _, span = text.partition("=")
    first, _, last = span.partition("-")
    if not (name and first.isdigit() and last.isdigit() and int(first) <= int(last)):
        raise ValueError(f"--group {text!r}: write NAME=FIRST-LAST, e.g. trained=30-59")
    return name, list(range(int(first), int(last) + 1))


def frame_indices(dataset, episodes: list[int], every: int) -> list[int]:
    """Every ``every``-th frame of each episode (dataset-wide indices)."""
    indices = []
    for episode in episodes:
        start = int(dataset.meta.episodes[episode]["dataset_from_index"])
        stop = int(dataset.meta.episodes[episode]["dataset_to_index"])
        indices.extend(range(start, stop, every))
    return indices


@torch.no_grad()
def executed_errors(policy, preprocessor, postprocessor, dataset, indices: list[int], batch_size: int):
    """Per frame: (mean over the executed steps of |predicted - recorded action|, the first step's)."""
    n_exec = policy.config.n_action_steps
    chunk_errors, first_errors = [], []
    for start in range(0, len(indices), batch_size):
        items = [dataset[i] for i in indices[start : start + batch_size]]
        batch = torch.utils.data.default_collate(items)
        recorded = batch[ACTION_KEY][:, :n_exec]  # (B, N, A), dataset units
        valid = ~batch[ACTION_IS_PAD_KEY][:, :n_exec]  # (B, N)
        predicted = policy.predict_action_chunk(preprocessor(batch))[:, :n_exec]
        predicted = postprocessor(predicted).to(recorded.dtype)  # (B, N, A), dataset units
        distance = (predicted - recorded).norm(dim=-1)  # (B, N)
        chunk_errors += ((distance * valid).sum(1) / valid.sum(1)).tolist()
        first_errors += distance[:, 0].tolist()
    return chunk_errors, first_errors


def _parse_args(argv: list[str] | None):
    parser = OneLineArgumentParser(prog="open_loop_error.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy-path", required=True, help="a SubgoalVLA pretrained_model folder")
    parser.add_argument("--dataset-root", required=True, help="a LeRobotDataset with the policy's inputs")
    parser.add_argument("--repo-id", default="local/metaworld", help="the dataset's repo id")
    parser.add_argument("--group", action="append", required=True, help="NAME=FIRST-LAST episodes (repeat)")
    parser.add_argument("--every", type=int, default=5, help="predict from every this-many-th frame")
    parser.add_argument("--batch-size", type=int, default=16, help="frames per forward pass")
    parser.add_argument("--seed", type=int, default=0, help="seeds the diffusion heads' noise")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    with user_errors(logger):
        args = _parse_args(argv)
        groups = [parse_group(text) for text in args.group]
        from lerobot.datasets import LeRobotDataset, LeRobotDatasetMetadata, resolve_delta_timestamps

        policy, preprocessor, postprocessor = load_policy(args.policy_path)
        policy.eval()
        meta = LeRobotDatasetMetadata(args.repo_id, root=args.dataset_root)
        last = meta.total_episodes - 1
        for name, episodes in groups:
            if episodes[-1] > last:
                raise ValueError(f"--group {name}: episode {episodes[-1]} is past the last one ({last})")
        dataset = LeRobotDataset(
            args.repo_id,
            root=args.dataset_root,
            delta_timestamps=resolve_delta_timestamps(policy.config, meta),
            video_backend="pyav",
        )
        torch.manual_seed(args.seed)
        print(f"{'group':<10} {'episodes':>8} {'frames':>7} {'median':>8} {'mean':>8} {'first med':>10}")
        for name, episodes in groups:
            indices = frame_indices(dataset, episodes, args.every)
            chunk, first = executed_errors(
                policy, preprocessor, postprocessor, dataset, indices, args.batch_size
            )
            print(
                f"{name:<10} {len(episodes):>8} {len(indices):>7} {statistics.median(chunk):>8.3f} "
                f"{statistics.fmean(chunk):>8.3f} {statistics.median(first):>10.3f}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
