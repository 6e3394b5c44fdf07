"""What a trained SubgoalVLA's encoding knows about the block it must grasp: linear probes, CALVIN play data.

The open-loop errors say that the CALVIN policies miss the gripper's yaw on lifts and rotations, and that
another episode's image barely moves that error: the policy does not turn the hand to the block. This tells
the two reasons apart. Either the encoding the heads read (the backbone's layer-k states, section 3.1) does
not hold the block's orientation (the vision tower never learned to see it), or it holds it and the heads do
not use it. A ridge regression from each feature source to the block's pose is fitted on some episodes and
scored on the others (``--folds``-fold cross-validation over runs of consecutive episodes); the same probe on
an untrained copy of the model and on the pooled camera pixels says what the architecture and the raw images
give without training, and a probe without features (``none``) is the chance row.

Targets, all of the block the episode's instruction names, read from ``observation.environment_state``
(CALVIN's scene_obs, named by ``calvin_vocab.SCENE_OBS_NAMES``: per block x, y, z, then XYZ Euler angles) and
``observation.state`` (robot_obs, ``calvin_vocab.ROBOT_OBS_NAMES``: the TCP's yaw, the last gripper command):
``yaw`` the block's yaw, ``yaw_grip`` its yaw relative to the TCP's (what the gripper camera shows and the
hand must turn by), both as (cos 2a, sin 2a) because a block looks the same turned by half a turn, and ``xy``
its position on the table. Only frames before the episode's first closing command enter (the approach, where
the yaw decides the grasp).

    python benchmarks/study/calvin_block_probe.py --policy-path RUN/pretrained_model \\
        --dataset-root outputs/all34x2/dataset --families lift rotate --every 3

Prints, per feature source and target, the held-out R^2 (1 = exact, 0 = the mean's) and, for the angles, the
median error in degrees (a probe that knows nothing is 45 degrees off on average). The ridge strength is the
best of a small grid on the held-out folds, for every source alike (a slightly optimistic R^2, the same for
all).

Dimension legend: ``F`` frames, ``D`` feature dim, ``T`` target dims, ``S`` tokens, ``E`` hidden width.
"""

from __future__ import annotations

import logging
import math
import sys
from pathlib import Path

import torch
from calvin_task_groups import FAMILIES, task_groups

from lerobot_subgoalvla.calvin_vocab import (
    BLOCK_COLORS,
    ROBOT_OBS_NAMES,
    SCENE_OBS_NAMES,
    TRAINING_ANNOTATIONS,
)
from lerobot_subgoalvla.cli_errors import OneLineArgumentParser, user_errors
from lerobot_subgoalvla.contract.keys import ENV_STATE_KEY, STATE_KEY
from lerobot_subgoalvla.visualization.checkpoint import load_policy

logger = logging.getLogger(__name__)

#: robot_obs indices: the TCP's yaw and the last gripper command (1 open, -1 close).
TCP_YAW, GRIPPER_COMMAND = ROBOT_OBS_NAMES.index("tcp_euler_z"), ROBOT_OBS_NAMES.index("gripper_action")
#: Ridge strengths, as multiples of the mean squared feature norm (scale-free across sources).
RIDGE_GRID = (1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0)
#: Side of the pooled image per camera for the ``pixels`` source.
PIXEL_SIDE = 24


def block_of(instruction: str) -> str | None:
    """The block colour every task with this training instruction names, or None (several, or none)."""
    colours = {
        colour
        for task, instructions in TRAINING_ANNOTATIONS.items()
        if instruction in instructions
        for colour in BLOCK_COLORS
        if f"_{colour}_" in f"_{task}_"
    }
    return colours.pop() if len(colours) == 1 else None


def approach_frames(states: torch.Tensor) -> int:
    """Frames before the first closing command, from an episode's (F, 15) robot_obs (all if none closes)."""
    closing = (states[:, GRIPPER_COMMAND] < 0).nonzero()
    return int(closing[0, 0]) if len(closing) else len(states)


def block_targets(environment: torch.Tensor, states: torch.Tensor, colour: str) -> dict[str, torch.Tensor]:
    """(F, 24) scene_obs and (F, 15) robot_obs -> target name -> (F, T) for the ``colour`` block."""
    slot = f"block_slot{BLOCK_COLORS.index(colour)}"  # the converter stores the blocks in this order
    x, yaw_index = SCENE_OBS_NAMES.index(f"{slot}_x"), SCENE_OBS_NAMES.index(f"{slot}_euler_z")
    yaw = environment[:, yaw_index].double()
    relative = yaw - states[:, TCP_YAW].double()
    return {
        "yaw": torch.stack([torch.cos(2 * yaw), torch.sin(2 * yaw)], dim=1),
        "yaw_grip": torch.stack([torch.cos(2 * relative), torch.sin(2 * relative)], dim=1),
        "xy": environment[:, x : x + 2].double(),
    }


def held_out_predictions(features: torch.Tensor, target: torch.Tensor, folds: torch.Tensor) -> dict:
    """Ridge strength -> held-out predictions (F, T), each fold predicted by a ridge fitted on the others.

    Ridge in its dual form (D may exceed F) on standardised features and centred targets; one eigen-
    decomposition of each fold's Gram matrix serves every strength, which multiplies the Gram's mean diagonal
    (the mean squared norm of a standardised row) so that one grid suits every source.
    """
    predictions = {strength: torch.empty_like(target) for strength in RIDGE_GRID}
    for fold in folds.unique():
        held = folds == fold
        mean, scale = features[~held].mean(0), features[~held].std(0) + 1e-6
        train_z, test_z = (features[~held] - mean) / scale, (features[held] - mean) / scale  # (F, D)
        gram = train_z @ train_z.T  # (F, F)
        eigenvalues, eigenvectors = torch.linalg.eigh(gram)
        offset = target[~held].mean(0)
        rotated = eigenvectors.T @ (target[~held] - offset)  # (F, T)
        cross = test_z @ train_z.T  # (F_held, F)
        for strength in RIDGE_GRID:
            # clamped: a source without features (``none``) has a zero Gram and predicts the mean
            shrink = 1 / (eigenvalues + strength * gram.diagonal().mean().clamp_min(1e-12))
            predictions[strength][held] = cross @ (eigenvectors @ (rotated * shrink[:, None])) + offset
    return predictions


def best_held_out(features: torch.Tensor, target: torch.Tensor, folds: torch.Tensor) -> torch.Tensor:
    """Held-out predictions (F, T) at the grid's strength with the best held-out R^2."""
    return max(held_out_predictions(features, target, folds).values(), key=lambda p: r_squared(p, target))


def r_squared(predicted: torch.Tensor, true: torch.Tensor) -> float:
    """Mean over target dims of 1 - SSE / SST."""
    residual = ((predicted - true) ** 2).sum(0)
    spread = ((true - true.mean(0)) ** 2).sum(0)
    return float((1 - residual / spread).mean())


def median_angle_error_degrees(predicted: torch.Tensor, true: torch.Tensor) -> float:
    """Median |a_pred - a_true| of (cos 2a, sin 2a) pairs, a modulo half a turn, in degrees (chance: 45)."""
    twice = torch.atan2(predicted[:, 1], predicted[:, 0]) - torch.atan2(true[:, 1], true[:, 0])
    wrapped = torch.remainder(twice + math.pi, 2 * math.pi) - math.pi  # 2 * error in (-pi, pi]
    return math.degrees(float((wrapped.abs() / 2).median()))


@torch.no_grad()
def feature_sources(models: dict, preprocessor, items: list[dict]) -> dict[str, torch.Tensor]:
    """Source name -> (F, D) float64 features of a batch of dataset items: each model's layer-k states of the
    image and instruction tokens (padding zeroed), the cameras pooled to PIXEL_SIDE, and no feature at all
    (``none``: the probe predicts the training folds' mean, the chance row)."""
    batch = preprocessor(torch.utils.data.default_collate(items))
    sources = {}
    for name, model in models.items():
        hidden, mask = model.encode(batch)  # (F, S, E), (F, S)
        sources[name] = (hidden * mask.unsqueeze(-1)).flatten(1).double()
    first = next(iter(models.values()))
    pooled = [torch.nn.functional.adaptive_avg_pool2d(batch[key], PIXEL_SIDE) for key in first.camera_keys]
    sources["pixels"] = torch.cat([p.flatten(1) for p in pooled], dim=1).double()
    sources["none"] = torch.zeros(len(items), 1, dtype=torch.float64)  # predicts the training mean: chance
    return sources


def episode_frames(dataset, episode: int, every: int) -> list[int]:
    """Every ``every``-th approach frame of an episode (dataset-wide indices)."""
    start = int(dataset.meta.episodes[episode]["dataset_from_index"])
    stop = int(dataset.meta.episodes[episode]["dataset_to_index"])
    states = torch.stack(dataset.hf_dataset.select_columns([STATE_KEY])[start:stop][STATE_KEY])  # (F, 15)
    return list(range(start, start + approach_frames(states), every))


def _parse_args(argv: list[str] | None):
    parser = OneLineArgumentParser(prog="calvin_block_probe.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy-path", required=True, help="a SubgoalVLA pretrained_model folder")
    parser.add_argument(
        "--dataset-root", type=Path, required=True, help="a LeRobotDataset converted from CALVIN"
    )
    parser.add_argument("--repo-id", default="local/calvin_demo", help="the dataset's repo id")
    parser.add_argument(
        "--families", nargs="+", default=["lift", "rotate", "push"], choices=sorted(FAMILIES),
        help="task families whose episodes are probed (each names one block)",
    )  # fmt: skip
    parser.add_argument("--per-family", type=int, default=200, help="episodes per family (the first ones)")
    parser.add_argument("--every", type=int, default=5, help="probe every this-many-th approach frame")
    parser.add_argument(
        "--folds", type=int, default=5,
        help="cross-validation folds: runs of consecutive episodes (play data keeps a scene across several)",
    )  # fmt: skip
    parser.add_argument("--batch-size", type=int, default=32, help="frames per forward pass")
    parser.add_argument("--seed", type=int, default=0, help="seeds the untrained copy's weights")
    return parser.parse_args(argv)


def _episodes(meta, families: list[str], per_family: int) -> list[tuple[int, str]]:
    """(episode, block colour) of the first ``per_family`` episodes of each family, in dataset order."""
    instruction = {int(e["episode_index"]): e["tasks"][0] for e in meta.episodes}
    groups = task_groups(sorted(instruction.items()), per_family)
    chosen = sorted(e for family in families for e in groups.get(family, []))
    colours = {e: block_of(instruction[e]) for e in chosen}
    return [(e, colour) for e, colour in colours.items() if colour is not None]


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    with user_errors(logger):
        args = _parse_args(argv)
        from lerobot.datasets import LeRobotDataset, LeRobotDatasetMetadata

        policy, preprocessor, _ = load_policy(args.policy_path)
        torch.manual_seed(args.seed)
        untrained = type(policy)(policy.config)
        models = {"trained": policy.model.eval(), "untrained": untrained.model.eval()}
        meta = LeRobotDatasetMetadata(args.repo_id, root=args.dataset_root)
        if ENV_STATE_KEY not in meta.features:
            raise ValueError(f"--dataset-root {args.dataset_root}: no {ENV_STATE_KEY}; convert CALVIN data")
        episodes = _episodes(meta, args.families, args.per_family)
        if len(episodes) < args.folds:
            raise ValueError(f"--families {args.families}: {len(episodes)} episodes, fewer than --folds")
        # One frame per item: the encoding reads the cameras and the instruction, not the action chunk.
        dataset = LeRobotDataset(args.repo_id, root=args.dataset_root, video_backend="pyav")
        fold_of = [rank * args.folds // len(episodes) for rank in range(len(episodes))]
        frames = [(i, colour, fold) for (e, colour), fold in zip(episodes, fold_of, strict=True)
                  for i in episode_frames(dataset, e, args.every)]  # fmt: skip
        print(f"{len(episodes)} episodes ({', '.join(args.families)}), {len(frames)} approach frames")
        features: dict[str, list[torch.Tensor]] = {}
        targets: dict[str, list[torch.Tensor]] = {}
        for start in range(0, len(frames), args.batch_size):
            chunk = frames[start : start + args.batch_size]
            items = [dataset[i] for i, _, _ in chunk]
            for name, value in feature_sources(models, preprocessor, items).items():
                features.setdefault(name, []).append(value)
            for item, (_, colour, _) in zip(items, chunk, strict=True):
                item_targets = block_targets(item[ENV_STATE_KEY][None], item[STATE_KEY][None], colour)
                for name, value in item_targets.items():
                    targets.setdefault(name, []).append(value)
        folds = torch.tensor([fold for _, _, fold in frames])
        print(f"{'source':<10} {'target':<9} {'R^2':>7} {'median deg':>11}")
        for source, parts in features.items():
            x = torch.cat(parts)
            for target_name, values in targets.items():
                y = torch.cat(values)
                predicted = best_held_out(x, y, folds)
                angle = "" if target_name == "xy" else f"{median_angle_error_degrees(predicted, y):>11.1f}"
                print(f"{source:<10} {target_name:<9} {r_squared(predicted, y):>7.3f} {angle}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
