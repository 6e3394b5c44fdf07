"""SubgoalVLA on Meta-World through LeRobot's own code: generated expert data -> ``subgoalvla-add-traces`` ->
``lerobot-train`` -> LeRobot's Meta-World env and evaluation loop, unchanged except for a short episode.

LeRobot's Meta-World env runs 500 steps per episode whatever ``--env.episode_length`` says (about two
minutes on this CPU); here the same ``eval_policy`` loop runs one episode cut to 6 steps, which exercises
every seam (the env's keys and instruction reach the policy, its actions reach the env) in seconds.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import REPO_ID
from helpers.tiny_training import train_tiny

from lerobot_subgoalvla.datasets_conversion.add_traces import add_traces


@pytest.fixture(scope="module")
def checkpoint(generated: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny SubgoalVLA trained for 2 steps on one generated reach-v3 episode (the Meta-World recipe's
    window: the paper's frame counts, docs/metaworld.md)."""
    work = tmp_path_factory.mktemp("subgoalvla_metaworld")
    overrides = {"trace_start": 14, "stride": 1}
    dataset = add_traces(REPO_ID, generated, work / "traces", window_overrides=overrides)
    return train_tiny(dataset.root, REPO_ID, work / "train")


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


def test_the_planned_traces_of_a_metaworld_episode_are_plotted(checkpoint: Path, tmp_path: Path) -> None:
    from lerobot_subgoalvla.visualization import trace_plot
    from lerobot_subgoalvla.visualization.checkpoint import load_policy

    policy, pre, post = load_policy(checkpoint)
    env_cfg = trace_plot.env_config("metaworld", "reach-v3")
    vector_env = trace_plot.make_single_env(env_cfg)
    try:
        for env in vector_env.envs:
            env.unwrapped._max_episode_steps = 6
        result = trace_plot.rollout_traces(policy, pre, post, vector_env, env_cfg, seed=1000)
    finally:
        vector_env.close()
    assert result.states.shape == (6, 4) and result.task == "Reach a goal position"
    assert result.plans and result.plans[0][0] == 0  # the first chunk is planned at the first step
    assert all(trace.shape == (8, 4) for _, trace in result.plans)
    assert list(result.trace_steps) == list(range(14, 22))  # the recipe's window: start 14, stride 1
    figure = tmp_path / "trace_plot.png"
    trace_plot.plot_trace_rollout(result, figure)
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
