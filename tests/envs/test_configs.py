"""CalvinEnvConfig: registration, validation, LeRobot features, and the task_id-per-chain layout."""

from __future__ import annotations

import pickle

import gymnasium as gym
import pytest
from lerobot.configs import FeatureType
from lerobot.envs.configs import EnvConfig
from lerobot.envs.utils import FreezeAfterEpisodeEnd, env_to_policy_features

from lerobot_subgoalvla.calvin_vocab import TASK_NAMES
from lerobot_subgoalvla.envs.calvin.configs import GYM_ID, CalvinEnvConfig


def test_registered_as_calvin() -> None:
    assert EnvConfig.get_choice_class("calvin") is CalvinEnvConfig
    cfg = CalvinEnvConfig()
    assert cfg.type == "calvin"
    assert cfg.task == "lh_mtlc"
    assert cfg.fps == 30
    assert list(cfg.chain_ids) == list(range(1000))


def test_policy_features_follow_lerobot_naming() -> None:
    cfg = CalvinEnvConfig(static_image_size=32, gripper_image_size=16)
    features = env_to_policy_features(cfg)
    assert features["observation.images.static"].shape == (3, 32, 32)
    assert features["observation.images.gripper"].shape == (3, 16, 16)
    assert features["observation.images.static"].type is FeatureType.VISUAL
    assert features["observation.state"].shape == (15,)
    assert features["observation.environment_state"].shape == (24,)
    assert features["observation.environment_state"].type is FeatureType.ENV
    assert features["action"].shape == (7,)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"task": "open_the_drawer"}, "open_drawer"),
        ({"scene": "calvin_E"}, "calvin_D"),
        ({"scene": "calvin_D"}, "--env.assets_dir"),
        ({"action_mode": "delta"}, "relative, absolute"),
        ({"fps": 15}, "30 Hz"),
        ({"chain_start": 5, "chain_stop": 5}, "chain_start < chain_stop"),
        ({"chain_stop": 1001}, "<= 1000"),
        ({"episode_length": 0}, "--env.episode_length"),
        ({"static_image_size": 0}, "--env.static_image_size"),
    ],
)
def test_bad_fields_name_the_flag_and_the_allowed_values(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        CalvinEnvConfig(**kwargs)


def test_gym_kwargs_round_trip_into_env_arguments() -> None:
    cfg = CalvinEnvConfig(
        task="open_drawer", episode_length=7, static_image_size=24, results_path="/tmp/r.jsonl"
    )
    kwargs = cfg.gym_kwargs
    assert kwargs["task"] == "open_drawer"
    assert kwargs["episode_length"] == 7
    assert kwargs["static_size"] == 24
    assert kwargs["results_path"] == "/tmp/r.jsonl"


def test_create_envs_one_lazy_task_id_per_chain() -> None:
    cfg = CalvinEnvConfig(chain_start=3, chain_stop=6, static_image_size=16, gripper_image_size=16)
    envs = cfg.create_envs(n_envs=2, use_async_envs=False)
    assert list(envs) == ["calvin"]
    assert list(envs["calvin"]) == [3, 4, 5]
    vec = envs["calvin"][4]
    assert vec.num_envs == 2
    assert not vec.is_alive  # nothing simulated until lerobot-eval resets it
    assert vec.single_observation_space["pixels"]["static"].shape == (16, 16, 3)
    assert vec.observation_space["agent_pos"].shape == (2, 15)
    assert vec.metadata["render_fps"] == 30
    # Each sub-env factory is a standard-picklable partial building a frozen CalvinEnv bound to chain 4.
    factory = pickle.loads(pickle.dumps(vec._env_fns[0]))
    env = factory()
    assert isinstance(env, FreezeAfterEpisodeEnd)
    assert list(env.unwrapped.chain_ids) == [4]
    env.close()


def test_create_envs_single_task_uses_the_calvin_task_id() -> None:
    cfg = CalvinEnvConfig(task="turn_on_led", static_image_size=16, gripper_image_size=16)
    envs = cfg.create_envs(n_envs=1)
    assert list(envs["calvin"]) == [TASK_NAMES.index("turn_on_led")]


def test_live_pool_keeps_at_most_max_parallel_tasks_alive() -> None:
    cfg = CalvinEnvConfig(chain_start=0, chain_stop=3, static_image_size=16, gripper_image_size=16)
    envs = cfg.create_envs(n_envs=1)["calvin"]
    descriptions = [envs[cid].call("task_description")[0] for cid in range(3)]
    assert [envs[cid].is_alive for cid in range(3)] == [False, False, True]
    assert all(isinstance(text, str) and text for text in descriptions)
    # A released env is rebuilt on its next use.
    assert envs[0].call("task_description")[0] == descriptions[0]
    assert envs[0].is_alive and not envs[2].is_alive
    for vec in envs.values():
        vec.close()
    assert isinstance(envs[0].single_action_space, gym.spaces.Box)


def test_gymnasium_make_builds_a_calvin_env() -> None:
    env = gym.make(GYM_ID, task="open_drawer", static_size=16, gripper_size=16, episode_length=5)
    assert type(env.unwrapped).__name__ == "CalvinEnv"
    assert env.unwrapped.task_description == "pull the handle to open the drawer"
    assert env.get_wrapper_attr("_max_episode_steps") == 5
    env.close()
