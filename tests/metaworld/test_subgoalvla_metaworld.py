"""SubgoalVLA on Meta-World through LeRobot's own code: generated expert data -> ``subgoalvla-add-traces`` ->
``lerobot-train`` -> LeRobot's Meta-World env and evaluation loop, unchanged except for a short episode.

LeRobot's Meta-World env runs 500 steps per episode whatever ``--env.episode_length`` says (about two
minutes on this CPU); here the same ``eval_policy`` loop runs one episode cut to 6 steps, which exercises
every seam (the env's keys and instruction reach the policy, its actions reach the env) in seconds.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO_ID

from lerobot_subgoalvla.datasets_conversion.add_traces import add_traces

BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def checkpoint(generated: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny SubgoalVLA trained for 2 steps on one generated reach-v3 episode (the Meta-World recipe's
    window: the paper's frame counts, docs/metaworld.md)."""
    work = tmp_path_factory.mktemp("subgoalvla_metaworld")
    overrides = {"trace_start": 14, "stride": 1}
    dataset = add_traces(REPO_ID, generated, work / "traces", window_overrides=overrides)
    flags = [
        "--policy.type=subgoalvla", "--policy.preset=tiny", "--policy.device=cpu",
        "--policy.push_to_hub=false",
        f"--dataset.repo_id={REPO_ID}", f"--dataset.root={dataset.root}", "--dataset.video_backend=pyav",
        f"--output_dir={work / 'train'}", "--steps=2", "--batch_size=2", "--num_workers=0", "--save_freq=2",
        "--wandb.enable=false",
    ]  # fmt: skip
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
    result = subprocess.run(
        [str(BIN / "lerobot-train"), *flags], capture_output=True, text=True, env=env, timeout=400
    )
    assert result.returncode == 0, (result.stdout + result.stderr)[-3000:]
    return work / "train" / "checkpoints" / "last" / "pretrained_model"


def test_a_tiny_subgoalvla_runs_an_episode_in_lerobots_metaworld_env(checkpoint: Path) -> None:
    from lerobot.envs import make_env, make_env_pre_post_processors
    from lerobot.envs.configs import MetaworldEnv
    from lerobot.policies import make_pre_post_processors
    from lerobot.scripts.lerobot_eval import eval_policy

    import lerobot_subgoalvla.plugin  # noqa: F401  (registers the policy type)
    from lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla import SubgoalVLAPolicy

    policy = SubgoalVLAPolicy.from_pretrained(checkpoint)
    assert policy.config.image_features_in_order == ["observation.image"]
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    env_cfg = MetaworldEnv(task="reach-v3")
    env_pre, env_post = make_env_pre_post_processors(env_cfg, policy.config)
    envs = make_env(env_cfg, n_envs=1)
    vector_env = next(iter(next(iter(envs.values())).values()))
    try:
        for env in vector_env.envs:
            env.unwrapped._max_episode_steps = 6
        info = eval_policy(vector_env, policy, env_pre, env_post, pre, post, n_episodes=1, start_seed=0)
    finally:
        vector_env.close()
    episode = info["per_episode"][0]
    assert episode["episode_ix"] == 0 and isinstance(episode["success"], bool)
    assert info["aggregated"]["avg_sum_reward"] >= 0
