"""The ground-truth subgoal traces of a converted dataset, drawn as ghost robots over its own frames.

``subgoalvla-render-traces`` shows what a checkpoint *plans*; this shows what the planner is trained to
predict: for every ``--every``-th frame of one episode, the simulator is put into the frame's state
(``observation.state`` = robot_obs, ``observation.environment_state`` = scene_obs, so the scene occludes
the ghosts as it should) and the frame's ``observation.subgoal_trace`` (robot_obs units, as stored) is drawn
over the recorded static image.

Command::

    subgoalvla-dataset-traces --dataset-root outputs/demo/dataset --episode 0 --output episode0.mp4

This needs a CALVIN dataset (the simulator re-poses CALVIN's robot and scene).

Dimension legend: ``M`` trace length, ``p`` proprio dim (15), ``H = W`` static image side.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import numpy as np

from lerobot_subgoalvla.cli_errors import OneLineArgumentParser, user_errors
from lerobot_subgoalvla.contract.calvin import GRIPPER_CAMERA_KEY, STATIC_CAMERA_KEY
from lerobot_subgoalvla.contract.keys import ENV_STATE_KEY, STATE_KEY, SUBGOAL_TRACE_KEY
from lerobot_subgoalvla.envs.calvin.protocol import SCENES
from lerobot_subgoalvla.visualization.ghost_robots import render_trace, write_trace_media

logger = logging.getLogger(__name__)


def dataset_trace_frames(
    root: Path, episode: int, every: int, scene: str = "procedural", assets_dir: str | None = None
) -> list[np.ndarray]:
    """One ghost overlay (H, W, 3) uint8 per ``every``-th frame of ``episode`` of the dataset at ``root``."""
    from lerobot.datasets import LeRobotDataset, LeRobotDatasetMetadata

    from lerobot_subgoalvla.envs.calvin.sim.simulation import CalvinSimulation

    if not (Path(root) / "meta" / "info.json").is_file():
        raise FileNotFoundError(f"--dataset-root {root}: no meta/info.json; pass a converted LeRobotDataset")
    if every < 1:
        raise ValueError(f"--every must be >= 1, got {every}")
    meta = LeRobotDatasetMetadata(f"local/{Path(root).name}", root=root)  # features only, no frames decoded
    missing = [
        k
        for k in (STATIC_CAMERA_KEY, GRIPPER_CAMERA_KEY, STATE_KEY, ENV_STATE_KEY, SUBGOAL_TRACE_KEY)
        if k not in meta.features
    ]
    if missing:
        raise ValueError(f"--dataset-root {root}: lacks {missing}; convert it with subgoalvla-convert-calvin")
    if not 0 <= episode < meta.total_episodes:
        raise ValueError(f"--episode {episode}: the dataset has episodes 0..{meta.total_episodes - 1}")
    dataset = LeRobotDataset(f"local/{Path(root).name}", root=root, video_backend="pyav", episodes=[episode])
    static_side = int(dataset.features[STATIC_CAMERA_KEY]["shape"][0])  # (H, W, 3)
    gripper_side = int(dataset.features[GRIPPER_CAMERA_KEY]["shape"][0])
    frames = []
    with CalvinSimulation(scene, assets_dir, static_side, gripper_side) as sim:
        for index in range(0, len(dataset), every):
            item = dataset[index]
            sim.reset(robot_obs=item[STATE_KEY].numpy(), scene_obs=item[ENV_STATE_KEY].numpy())
            image = item[STATIC_CAMERA_KEY].permute(1, 2, 0).numpy()  # (H, W, 3) in [0, 1]
            image = np.rint(image * 255).astype(np.uint8)
            frames.append(render_trace(sim, item[SUBGOAL_TRACE_KEY].numpy(), image))  # trace (M, p)
    logger.info("episode %d: %d frames drawn (every %d of %d)", episode, len(frames), every, len(dataset))
    return frames


def main(argv: list[str] | None = None) -> int:
    """``subgoalvla-dataset-traces``: write one episode's ground-truth traces to ``--output``."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    parser = OneLineArgumentParser(prog="subgoalvla-dataset-traces", description=__doc__.splitlines()[0])
    parser.add_argument("--dataset-root", type=Path, required=True, help="a converted LeRobotDataset folder")
    parser.add_argument("--episode", type=int, default=0, help="episode index")
    parser.add_argument("--every", type=int, default=10, help="draw every N-th frame")
    parser.add_argument("--scene", default="procedural", choices=SCENES, help="the scene the data comes from")
    parser.add_argument("--assets-dir", default=None, help="calvin_env clone (for the calvin_* scenes)")
    parser.add_argument("--fps", type=int, default=5, help="frame rate of an .mp4")
    parser.add_argument(
        "--output", required=True, help="traces.mp4 (video) or strip.png (frames side by side)"
    )
    with user_errors(logger):
        args = parser.parse_args(argv)
        if Path(args.output).suffix not in (".mp4", ".png"):
            raise ValueError(
                f"--output {args.output}: use a .mp4 (video) or .png (strip of frames) file name"
            )
        frames = dataset_trace_frames(
            args.dataset_root, args.episode, args.every, args.scene, args.assets_dir
        )
        write_trace_media(frames, args.output, fps=args.fps)
    return 0


if __name__ == "__main__":
    sys.exit(main())
