"""Run LeRobot's evaluation loop (``eval_policy_all``, what ``lerobot-eval`` calls) over a chain range.

A stand-still ACT and an oracle that completes a fixed set of tasks make each chain's result known and
different from chain to chain. Used by test_eval_resume.py in process and, to be killed, as a script:
``python eval_shard.py RESULTS_PATH START STOP [resume] [SECONDS_PER_STEP]``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import torch
from lerobot.configs import FeatureType
from lerobot.envs.utils import env_to_policy_features
from lerobot.policies.act.configuration_act import ACTConfig
from lerobot.policies.act.modeling_act import ACTPolicy
from lerobot.policies.act.processor_act import make_act_pre_post_processors
from lerobot.scripts.lerobot_eval import eval_policy_all

from lerobot_subgoalvla.envs.calvin import env as env_module
from lerobot_subgoalvla.envs.calvin.configs import CalvinEnvConfig

#: Tasks the oracle counts as done at their first step: chains reach different lengths.
DOABLE = {"open_drawer", "turn_on_led", "move_slider_left", "lift_red_block_table", "rotate_blue_block_right"}


class DoableOracle:
    def is_completed(self, task: str, start_info: dict, end_info: dict) -> bool:
        return task in DOABLE


class StandStill(ACTPolicy):
    seconds_per_step = 0.0

    def select_action(self, batch: dict) -> torch.Tensor:
        time.sleep(self.seconds_per_step)  # gives the test a window to kill the run between chains
        action = torch.zeros(len(batch["task"]), 7)
        action[:, -1] = 1.0
        return action


def evaluate(
    results: Path, start: int, stop: int, resume: bool = False, seconds_per_step: float = 0.0
) -> dict:
    cfg = CalvinEnvConfig(chain_start=start, chain_stop=stop, episode_length=3, static_image_size=16,
                          gripper_image_size=16, results_path=str(results), resume=resume)  # fmt: skip
    features = env_to_policy_features(cfg)
    config = ACTConfig(
        input_features={k: v for k, v in features.items() if v.type is not FeatureType.ACTION},
        output_features={"action": features["action"]}, device="cpu", push_to_hub=False, chunk_size=2,
        n_action_steps=2, dim_model=8, n_heads=1, dim_feedforward=8, n_encoder_layers=1,
        n_decoder_layers=1, use_vae=False, pretrained_backbone_weights=None,
    )  # fmt: skip
    policy = StandStill(config)
    policy.seconds_per_step = seconds_per_step
    pre, post = make_act_pre_post_processors(config, dataset_stats=None)
    env_pre, env_post = cfg.get_env_processors()
    real_oracle, env_module.TaskOracle = env_module.TaskOracle, DoableOracle  # restored below: tests share it
    envs = {"calvin": {}}
    try:
        envs = cfg.create_envs(n_envs=1, use_async_envs=False)
        return eval_policy_all(envs, policy, env_pre, env_post, pre, post, n_episodes=1, start_seed=1000)
    finally:
        for view in envs["calvin"].values():
            view.close()
        env_module.TaskOracle = real_oracle


if __name__ == "__main__":
    path, first, last = Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
    evaluate(path, first, last, resume="resume" in sys.argv[4:5], seconds_per_step=float(sys.argv[5]))
