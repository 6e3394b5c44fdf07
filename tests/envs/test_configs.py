"""CalvinEnvConfig: registration, validation, LeRobot features, and the task_id-per-chain layout."""

from __future__ import annotations

import pickle
import threading
from concurrent.futures import ThreadPoolExecutor

import gymnasium as gym
import pytest
from lerobot.configs import FeatureType
from lerobot.envs.configs import EnvConfig
from lerobot.envs.utils import env_to_policy_features

from lerobot_subgoalvla.calvin_vocab import EVAL_INSTRUCTIONS, TASK_NAMES
from lerobot_subgoalvla.config_error import ConfigError
from lerobot_subgoalvla.envs.calvin.configs import CalvinEnvConfig
from lerobot_subgoalvla.envs.calvin.env import official_chains
from lerobot_subgoalvla.envs.calvin.protocol import GYM_ID
from lerobot_subgoalvla.envs.calvin.vector import FrozenAfterEpisodeEnd


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
    with pytest.raises(ConfigError, match=message):
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


def test_create_envs_one_task_id_per_chain_sharing_one_lazy_vector_env() -> None:
    cfg = CalvinEnvConfig(
        chain_start=3, chain_stop=6, episode_length=4, static_image_size=16, gripper_image_size=16
    )
    envs = cfg.create_envs(n_envs=2, use_async_envs=False)
    assert list(envs) == ["calvin"]
    assert list(envs["calvin"]) == [3, 4, 5]
    vec = envs["calvin"][4]
    shared = vec._shared
    assert all(view._shared is shared for view in envs["calvin"].values())
    assert shared.num_alive == 0  # nothing simulated until lerobot-eval resets a task
    assert vec.num_envs == 2
    assert vec.single_observation_space["pixels"]["static"].shape == (16, 16, 3)
    assert vec.observation_space["agent_pos"].shape == (2, 15)
    assert vec.metadata["render_fps"] == 30
    # Each view pins its chain into reset, whatever LeRobot's rollout passes; one vector env serves all.
    for cid in (5, 3, 4):
        _, info = envs["calvin"][cid].reset(seed=[0, 1], options={"lerobot_new_rollout": True})
        assert list(info["chain_id"]) == [cid, cid]
        expected = EVAL_INSTRUCTIONS[official_chains()[cid].tasks[0]]
        assert envs["calvin"][cid].call("task_description") == (expected, expected)
    assert shared.num_alive == 1
    for view in envs["calvin"].values():
        view.close()
    assert shared.num_alive == 0


def test_sub_env_factory_pickles_with_the_standard_pickle() -> None:
    cfg = CalvinEnvConfig(chain_start=7, chain_stop=9, static_image_size=16, gripper_image_size=16)
    view = cfg.create_envs(n_envs=1)["calvin"][8]
    env = pickle.loads(pickle.dumps(view._shared.env_fns[0]))()
    assert isinstance(env, FrozenAfterEpisodeEnd)
    assert list(env.unwrapped.chain_ids) == [7, 8]
    env.close()


def test_create_envs_single_task_uses_the_calvin_task_id() -> None:
    cfg = CalvinEnvConfig(task="turn_on_led", static_image_size=16, gripper_image_size=16)
    envs = cfg.create_envs(n_envs=1)
    assert list(envs["calvin_turn_on_led"]) == [TASK_NAMES.index("turn_on_led")]


def test_each_evaluating_thread_gets_its_own_vector_env() -> None:
    cfg = CalvinEnvConfig(chain_start=0, chain_stop=2, static_image_size=16, gripper_image_size=16)
    envs = cfg.create_envs(n_envs=1)["calvin"]
    both_running = threading.Barrier(2)

    def vector_env_of_this_thread(cid: int) -> int:
        built = envs[cid]._shared.get()
        both_running.wait(timeout=120)  # two threads evaluate at the same time
        return id(built)

    with ThreadPoolExecutor(max_workers=2) as pool:
        built = list(pool.map(vector_env_of_this_thread, [0, 1]))
    assert len(set(built)) == 2 == envs[0]._shared.num_alive
    assert envs[0]._shared.get() is envs[0]._shared.get()  # same thread, same vector env
    envs[0].close()


def test_gymnasium_make_builds_a_calvin_env() -> None:
    env = gym.make(GYM_ID, task="open_drawer", static_size=16, gripper_size=16, episode_length=5)
    assert type(env.unwrapped).__name__ == "CalvinEnv"
    assert env.unwrapped.task_description == "pull the handle to open the drawer"
    assert env.get_wrapper_attr("_max_episode_steps") == 5
    env.close()


def test_paths_are_checked_when_the_config_is_made(tmp_path) -> None:
    with pytest.raises(ConfigError, match="--env.assets_dir: CALVIN asset missing"):
        CalvinEnvConfig(scene="calvin_D", assets_dir=str(tmp_path))
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(ConfigError, match="--env.results_path=.*cannot write there"):
        CalvinEnvConfig(results_path=str(tmp_path / "a_file" / "results.jsonl"))
    CalvinEnvConfig(results_path=str(tmp_path / "new" / "results.jsonl"))  # a folder still to be made is fine
