"""See what SubgoalVLA plans: its predicted subgoal traces drawn as ghost robots (paper figure 7).

The planner predicts a trace of M future robot states per action chunk (paper section 4.2, eq. 3) in the
*normalised* proprioceptive space. This module runs a trained policy in a :class:`CalvinEnv` the way
``lerobot-eval`` does (raw observation -> ``preprocess_observation`` -> pre-processor -> ``select_action`` ->
post-processor -> ``env.step``) and, at every step where a new chunk was planned, maps the policy's
``last_subgoal_trace`` back to ``robot_obs`` units with the very statistics the pre-processor normalised
``observation.state`` with, then draws it over the static camera image with ``render_trace``.

It is the one module that imports both the policy and the simulator (the policy and the envs never import each
other); nothing imports it.

Command::

    subgoalvla-render-traces --policy-path outputs/train/<run>/checkpoints/last/pretrained_model \\
        --task open_drawer --steps 60 --output traces.mp4     # or strip.png

Dimension legend: ``B`` batch (1 here), ``M`` trace length, ``p`` proprio dim (15), ``H = W`` static image
side.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lerobot.configs import FeatureType
from lerobot.envs.utils import preprocess_observation

from lerobot_subgoalvla.calvin_vocab import TASK_NAMES
from lerobot_subgoalvla.cli_errors import OneLineArgumentParser, user_errors
from lerobot_subgoalvla.contract.calvin import GRIPPER_CAMERA_KEY, STATIC_CAMERA_KEY
from lerobot_subgoalvla.contract.keys import TASK_KEY
from lerobot_subgoalvla.envs.calvin.env import CalvinEnv
from lerobot_subgoalvla.envs.calvin.protocol import LH_MTLC, SCENES
from lerobot_subgoalvla.visualization.checkpoint import load_policy, unnormalize_state
from lerobot_subgoalvla.visualization.ghost_robots import render_trace, write_trace_media

logger = logging.getLogger(__name__)


def rollout_with_traces(
    policy: Any, preprocessor: Any, postprocessor: Any, env: CalvinEnv, num_steps: int, seed: int
) -> list[np.ndarray]:
    """Run ``policy`` in ``env`` for up to ``num_steps`` steps; one ghost overlay per planned chunk.

    Args:
        policy: A SubgoalVLA policy with a planner (it exposes ``last_subgoal_trace``).
        preprocessor: The policy's pre-processor (its ``observation.state`` statistics un-normalise the
            trace).
        postprocessor: The policy's post-processor (un-normalises the actions).
        env: A single (not vectorised) ``CalvinEnv``; reset here with ``seed``.
        num_steps: Environment steps at most (the rollout stops earlier when the episode ends).
        seed: Seeds the env's reset and the samplers' noise (``torch.manual_seed``).

    Returns:
        ``(H, W, 3)`` uint8 static-camera frames, each showing the trace planned at that step as ghost robots
        over the observation the plan was made from.

    Raises:
        ValueError: ``num_steps`` < 1, or the policy has no planner (no trace is ever predicted).
    """
    if num_steps < 1:
        raise ValueError(f"num_steps={num_steps} must be >= 1")
    if getattr(policy.config, "use_planner", True) is False:
        raise ValueError(
            "this checkpoint was trained without the subgoal planner (use_planner=false): no traces"
        )
    torch.manual_seed(seed)
    policy.eval()
    policy.reset()
    observation, _ = env.reset(seed=seed)
    frames: list[np.ndarray] = []
    for step in range(num_steps):
        batch = preprocess_observation(observation)  # (1, ...) tensors, images CHW in [0, 1]
        batch = preprocessor({**batch, TASK_KEY: [env.task_description]})
        previous = policy.last_subgoal_trace
        with torch.inference_mode():
            action = postprocessor(policy.select_action(batch))  # (1, A)
        trace = policy.last_subgoal_trace
        if trace is not None and trace is not previous:  # a new chunk (and trace) was planned at this step
            rows = unnormalize_state(preprocessor, trace[0].float().cpu())  # (M, p)
            frame = np.asarray(observation["pixels"]["static"])
            frames.append(render_trace(env.simulation, rows.numpy(), frame))
        observation, _, terminated, truncated, _ = env.step(action[0].cpu().numpy())
        if terminated or truncated:
            logger.info("episode ended after %d step(s) (terminated=%s)", step + 1, terminated)
            break
    return frames


def _image_side(policy: Any, key: str) -> int:
    feature = policy.config.input_features.get(key)
    if feature is None or feature.type != FeatureType.VISUAL:
        raise ValueError(f"the checkpoint's policy has no {key!r} camera input; it cannot run in CalvinEnv")
    return int(feature.shape[-1])  # (3, H, W)


def _parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = OneLineArgumentParser(
        prog="subgoalvla-render-traces",
        description="Roll a SubgoalVLA checkpoint out in CALVIN; draw its planned subgoal traces as ghosts",
    )
    parser.add_argument("--policy-path", required=True, help="checkpoint dir (config.json + processors)")
    parser.add_argument("--task", required=True, choices=(LH_MTLC, *TASK_NAMES), help="task or lh_mtlc")
    parser.add_argument("--scene", default="procedural", choices=SCENES)
    parser.add_argument("--assets-dir", default=None, help="calvin_env clone (for the calvin_* scenes)")
    parser.add_argument("--chain", type=int, default=0, help="chain id for --task lh_mtlc")
    parser.add_argument("--steps", type=int, default=60, help="environment steps at most")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fps", type=int, default=5, help="frame rate of an .mp4 (one frame per chunk)")
    parser.add_argument(
        "--output", required=True, help="traces.mp4 (video) or strip.png (frames side by side)"
    )
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """``subgoalvla-render-traces``: write the ghost overlays of one rollout to ``--output``."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("lerobot_subgoalvla").setLevel(logging.INFO)  # also when an import configured logging
    with user_errors(logger):
        args = _parse_args(argv)
        if Path(args.output).suffix not in (".mp4", ".png"):
            raise ValueError(
                f"--output {args.output}: use a .mp4 (video) or .png (strip of frames) file name"
            )
        policy, preprocessor, postprocessor = load_policy(args.policy_path)
        env = CalvinEnv(
            args.task,
            scene=args.scene,
            assets_dir=args.assets_dir,
            chain_start=args.chain,
            chain_stop=args.chain + 1,
            episode_length=args.steps,
            static_size=_image_side(policy, STATIC_CAMERA_KEY),
            gripper_size=_image_side(policy, GRIPPER_CAMERA_KEY),
        )
        try:
            frames = rollout_with_traces(policy, preprocessor, postprocessor, env, args.steps, args.seed)
        finally:
            env.close()
        write_trace_media(frames, args.output, fps=args.fps)
    return 0


if __name__ == "__main__":
    sys.exit(main())
