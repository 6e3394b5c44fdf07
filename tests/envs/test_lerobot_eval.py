"""The env/eval contract: lerobot's eval loop over CalvinEnvConfig's task_id-per-chain envs.

- In process, with a scripted oracle: ``avg_sum_reward`` is the mean number of completed subtasks and
  ``pc_success`` the 5/5 rate, chain by chain.
- End to end, ``lerobot-eval --env.type=calvin`` in a subprocess with a saved LeRobot policy (ACT, random tiny
  weights; the env contract does not depend on the policy; and, marked slow, a tiny SubgoalVLA checkpoint):
  one task_id per chain, ``eval_info.json``'s ``avg_sum_reward`` equals the mean ``num_completed`` of the
  env's JSON-lines results, videos are written.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.vocabulary import calvin_backbone
from lerobot.configs import FeatureType
from lerobot.envs.utils import env_to_policy_features
from lerobot.policies.act.configuration_act import ACTConfig
from lerobot.policies.act.modeling_act import ACTPolicy
from lerobot.policies.act.processor_act import make_act_pre_post_processors
from lerobot.scripts.lerobot_eval import eval_policy_all

from lerobot_subgoalvla.calvin_vocab import EVAL_INSTRUCTIONS
from lerobot_subgoalvla.envs.calvin import env as env_module
from lerobot_subgoalvla.envs.calvin.configs import CalvinEnvConfig
from lerobot_subgoalvla.envs.calvin.env import official_chains
from lerobot_subgoalvla.envs.calvin.evaluation.chains import read_episode_results

TINY = {"static_image_size": 32, "gripper_image_size": 32}


class StandStillACT(ACTPolicy):
    """A real LeRobot policy class whose actions stand still (gripper open); records the instructions it
    got."""

    def __init__(self, config: ACTConfig) -> None:
        super().__init__(config)
        self.tasks: list[list[str]] = []  # per rollout, the instruction of every step

    def reset(self) -> None:
        super().reset()
        if getattr(self, "tasks", None) is not None:  # ACTPolicy.__init__ already calls reset()
            self.tasks.append([])

    def select_action(self, batch: dict) -> torch.Tensor:
        self.tasks[-1].append(batch["task"][0])
        action = torch.zeros(len(batch["task"]), 7)
        action[:, -1] = 1.0
        return action


def _tiny_act_config(cfg: CalvinEnvConfig) -> ACTConfig:
    """ACT with random tiny weights and no pretrained backbone download, on the env's features."""
    features = env_to_policy_features(cfg)
    return ACTConfig(
        input_features={k: v for k, v in features.items() if v.type is not FeatureType.ACTION},
        output_features={"action": features["action"]},
        device="cpu",
        push_to_hub=False,
        chunk_size=4,
        n_action_steps=4,
        dim_model=16,
        n_heads=2,
        dim_feedforward=32,
        n_encoder_layers=1,
        n_decoder_layers=1,
        use_vae=False,
        pretrained_backbone_weights=None,
    )


def _leading_count(tasks: tuple[str, ...], doable: set[str]) -> int:
    count = 0
    for task in tasks:
        if task not in doable:
            break
        count += 1
    return count


def test_eval_policy_all_reports_chain_lengths(monkeypatch: pytest.MonkeyPatch) -> None:
    chains = official_chains()
    doable = set(chains[0].tasks) | {chains[2].tasks[0]}  # chain 0: 5/5; others: their leading doable tasks

    class DoableOracle:
        """Completes the current subtask at its first step iff its task is in ``doable``."""

        def is_completed(self, task: str, start_info: dict, end_info: dict) -> bool:
            return task in doable

    monkeypatch.setattr(env_module, "TaskOracle", DoableOracle)
    cfg = CalvinEnvConfig(chain_start=0, chain_stop=4, episode_length=3, **TINY)
    envs = cfg.create_envs(n_envs=1, use_async_envs=False)
    config = _tiny_act_config(cfg)
    policy = StandStillACT(config)
    preprocessor, postprocessor = make_act_pre_post_processors(config, dataset_stats=None)
    env_preprocessor, env_postprocessor = cfg.get_env_processors()
    info = eval_policy_all(
        envs,
        policy,
        env_preprocessor,
        env_postprocessor,
        preprocessor,
        postprocessor,
        n_episodes=1,
        start_seed=1000,
    )
    expected = [_leading_count(chains[cid].tasks, doable) for cid in range(4)]
    per_task = {entry["task_id"]: entry["metrics"] for entry in info["per_task"]}
    assert sorted(per_task) == [0, 1, 2, 3]
    assert [per_task[cid]["sum_rewards"][0] for cid in range(4)] == expected
    assert [per_task[cid]["successes"][0] for cid in range(4)] == [n == 5 for n in expected]
    group = info["per_group"]["calvin"]
    assert group["avg_sum_reward"] == pytest.approx(np.mean(expected))
    assert group["pc_success"] == pytest.approx(100.0 * np.mean([n == 5 for n in expected]))
    # The policy saw chain 0's instruction switch after every completed subtask (one step each).
    assert policy.tasks[0] == [EVAL_INSTRUCTIONS[t] for t in chains[0].tasks]
    for vec in envs["calvin"].values():
        vec.close()


def _save_tiny_act(cfg: CalvinEnvConfig, path: Path) -> None:
    """A tiny random ACT and its processors, saved like a training checkpoint."""
    config = _tiny_act_config(cfg)
    ACTPolicy(config).save_pretrained(path)
    preprocessor, postprocessor = make_act_pre_post_processors(config, dataset_stats=None)
    preprocessor.save_pretrained(path)
    postprocessor.save_pretrained(path)


def _run_lerobot_eval_and_check(policy_dir: Path, tmp_path: Path, chains: tuple[int, int]) -> None:
    """Run ``lerobot-eval`` on chains ``[start, stop)`` and check eval_info.json against the env's records."""
    start, stop = chains
    results = tmp_path / "results.jsonl"
    command = [
        str(Path(sys.executable).with_name("lerobot-eval")),
        f"--policy.path={policy_dir}",
        "--policy.device=cpu",
        "--env.type=calvin",
        "--env.task=lh_mtlc",
        f"--env.chain_start={start}",
        f"--env.chain_stop={stop}",
        "--env.episode_length=3",
        "--env.static_image_size=32",
        "--env.gripper_image_size=32",
        f"--env.results_path={results}",
        "--eval.n_episodes=1",
        "--eval.batch_size=1",
        f"--output_dir={tmp_path / 'eval'}",
    ]
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "MPLBACKEND": "Agg"}
    run = subprocess.run(command, capture_output=True, text=True, env=env, timeout=900, check=False)
    assert run.returncode == 0, run.stderr[-3000:]
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    chain_ids = list(range(start, stop))
    assert sorted(entry["task_id"] for entry in info["per_task"]) == chain_ids
    records = {r.chain_id: r for r in read_episode_results(results)}
    assert sorted(records) == chain_ids
    assert all(records[cid].tasks == official_chains()[cid].tasks for cid in chain_ids)
    completed = [records[cid].num_completed for cid in chain_ids]
    assert info["per_group"]["calvin"]["avg_sum_reward"] == pytest.approx(np.mean(completed))
    assert info["per_group"]["calvin"]["n_episodes"] == len(chain_ids)
    for entry in info["per_task"]:
        assert entry["metrics"]["sum_rewards"] == [records[entry["task_id"]].num_completed]
        assert Path(entry["metrics"]["video_paths"][0]).is_file()


def test_lerobot_eval_cli_end_to_end(tmp_path: Path) -> None:
    cfg = CalvinEnvConfig(chain_start=5, chain_stop=7, episode_length=3, **TINY)
    _save_tiny_act(cfg, tmp_path / "policy")
    _run_lerobot_eval_and_check(tmp_path / "policy", tmp_path, chains=(5, 7))


@pytest.mark.slow
def test_lerobot_eval_with_a_tiny_subgoalvla_checkpoint(tmp_path: Path) -> None:
    from lerobot_subgoalvla.policies.subgoalvla.configuration_subgoalvla import SubgoalVLAConfig
    from lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla import SubgoalVLAPolicy
    from lerobot_subgoalvla.policies.subgoalvla.processor_subgoalvla import (
        make_subgoalvla_pre_post_processors,
    )

    features = env_to_policy_features(CalvinEnvConfig(**TINY))
    config = SubgoalVLAConfig(
        device="cpu",
        preset="tiny",
        backbone=calvin_backbone(),
        push_to_hub=False,
        input_features={k: v for k, v in features.items() if v.type is not FeatureType.ACTION},
        output_features={"action": features["action"]},
    )
    policy_dir = tmp_path / "policy"
    SubgoalVLAPolicy(config).save_pretrained(policy_dir)
    import torch

    # The proprio normaliser needs the state's statistics (a training run takes them from the dataset).
    stats = {"observation.state": {"mean": torch.zeros(15), "std": torch.ones(15)},
             "action": {"min": -torch.ones(7), "max": torch.ones(7)}}  # fmt: skip
    for pipeline in make_subgoalvla_pre_post_processors(config, dataset_stats=stats):
        pipeline.save_pretrained(policy_dir)
    _run_lerobot_eval_and_check(policy_dir, tmp_path, chains=(0, 2))
