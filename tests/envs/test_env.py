"""CalvinEnv: gymnasium contract, determinism, pickling, vector envs, chain scoring, single tasks, bad
inputs."""

from __future__ import annotations

import pickle
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from lerobot_subgoalvla.calvin_vocab import EVAL_INSTRUCTIONS
from lerobot_subgoalvla.envs.calvin.env import CalvinEnv, official_chains
from lerobot_subgoalvla.envs.calvin.evaluation.chains import EVAL_ROBOT_OBS, read_episode_results
from lerobot_subgoalvla.envs.calvin.expert.scripted_expert import ScriptedExpert, is_feasible

SMALL = {"static_size": 32, "gripper_size": 16}


class ScriptedOracle:
    """Completes the current subtask whenever ``complete`` is set; records what the env asked."""

    def __init__(self) -> None:
        self.complete = False
        self.calls: list[tuple[str, dict, dict]] = []

    def is_completed(self, task: str, start_info: dict, end_info: dict) -> bool:
        self.calls.append((task, start_info, end_info))
        return self.complete


@pytest.fixture
def chain_env() -> CalvinEnv:
    env = CalvinEnv("lh_mtlc", chain_start=0, chain_stop=1, episode_length=4, **SMALL)
    yield env
    env.close()


def _step(env: CalvinEnv, complete: bool) -> tuple[Any, ...]:
    env._oracle.complete = complete
    return env.step(np.zeros(7, dtype=np.float32))


def _rollout(env: CalvinEnv, seed: int, n: int) -> list[dict[str, Any]]:
    obs, _ = env.reset(seed=seed)
    actions = np.random.default_rng(seed).uniform(-1, 1, size=(n, 7)).astype(np.float32)
    observations = [obs]
    for action in actions:
        observations.append(env.step(action)[0])
    return observations


def _assert_same_obs(a: dict[str, Any], b: dict[str, Any]) -> None:
    np.testing.assert_array_equal(a["pixels"]["static"], b["pixels"]["static"])
    np.testing.assert_array_equal(a["pixels"]["gripper"], b["pixels"]["gripper"])
    np.testing.assert_array_equal(a["agent_pos"], b["agent_pos"])
    np.testing.assert_array_equal(a["environment_state"], b["environment_state"])


@pytest.mark.parametrize("action_mode", ["relative", "absolute"])
def test_gymnasium_check_env(action_mode: str) -> None:
    env = CalvinEnv(
        "lh_mtlc", chain_start=0, chain_stop=4, episode_length=8, action_mode=action_mode, **SMALL
    )
    check_env(env, skip_render_check=False)
    env.close()


def test_spaces_and_first_observation(chain_env: CalvinEnv) -> None:
    obs, info = chain_env.reset(seed=0)
    assert obs["pixels"]["static"].shape == (32, 32, 3) and obs["pixels"]["static"].dtype == np.uint8
    assert obs["pixels"]["gripper"].shape == (16, 16, 3)
    assert chain_env.observation_space.contains(obs)
    np.testing.assert_allclose(obs["agent_pos"][7:14], EVAL_ROBOT_OBS[7:14], atol=1e-4)
    np.testing.assert_allclose(obs["environment_state"][:6], official_chains()[0].scene_obs[:6], atol=1e-3)
    assert info == {"is_success": False, "num_completed": 0, "subtask_index": 0, "chain_id": 0}
    assert chain_env._max_episode_steps == 5 * 4
    frame = chain_env.render()
    assert frame.dtype == np.uint8 and frame.shape == (32, 32, 3)
    np.testing.assert_array_equal(frame, obs["pixels"]["static"])


def test_same_seed_same_rollout() -> None:
    make = partial(CalvinEnv, "lh_mtlc", chain_start=0, chain_stop=50, episode_length=20, **SMALL)
    first, second = make(), make()
    run_a, run_b = _rollout(first, seed=7, n=12), _rollout(second, seed=7, n=12)
    assert first._chain_id == second._chain_id
    for a, b in zip(run_a, run_b, strict=True):
        _assert_same_obs(a, b)
    # The same env replays the same rollout after another episode.
    for a, b in zip(run_a, _rollout(first, seed=7, n=12), strict=True):
        _assert_same_obs(a, b)
    first.close()
    second.close()


def test_reset_seed_picks_the_chain_and_option_overrides_it() -> None:
    env = CalvinEnv("lh_mtlc", chain_start=10, chain_stop=20, episode_length=4, **SMALL)
    picked = {env.reset(seed=seed)[1]["chain_id"] for seed in range(12)}
    assert picked <= set(range(10, 20)) and len(picked) > 1
    _, info = env.reset(seed=0, options={"chain_id": 13, "lerobot_new_rollout": True})
    assert info["chain_id"] == 13
    assert env.task_description == EVAL_INSTRUCTIONS[official_chains()[13].tasks[0]]
    with pytest.raises(ValueError, match=r"chain_id=25 is not in this env's chain range \[10, 20\)"):
        env.reset(options={"chain_id": 25})
    env.close()


def test_unstarted_env_pickles_and_runs_after_unpickling() -> None:
    env = pickle.loads(pickle.dumps(CalvinEnv("open_drawer", episode_length=4, **SMALL)))
    obs, _ = env.reset(seed=1)
    assert obs["agent_pos"].shape == (15,)
    env.close()


def test_chain_rewards_description_switch_and_success(chain_env: CalvinEnv, tmp_path: Path) -> None:
    chain_env._oracle = ScriptedOracle()
    chain_env.results_path = tmp_path / "results.jsonl"
    tasks = official_chains()[0].tasks
    chain_env.reset(seed=0)
    assert chain_env.task_description == EVAL_INSTRUCTIONS[tasks[0]]
    total = 0.0
    for k in range(5):
        _, reward, terminated, truncated, info = _step(chain_env, complete=False)
        assert reward == 0.0 and not terminated and not truncated
        _, reward, terminated, truncated, info = _step(chain_env, complete=True)
        total += reward
        assert reward == 1.0 and info["num_completed"] == k + 1
        assert terminated == (k == 4) and info["is_success"] == (k == 4) and not truncated
        if k < 4:
            assert chain_env.task_description == EVAL_INSTRUCTIONS[tasks[k + 1]]
    assert total == 5.0
    # The oracle was asked only about the current subtask, from the info at which that subtask started.
    asked = [task for task, _, _ in chain_env._oracle.calls]
    assert asked == [t for t in tasks for _ in range(2)]
    assert chain_env._oracle.calls[2][1] is chain_env._oracle.calls[1][2]
    with pytest.raises(RuntimeError, match="after the episode ended"):
        _step(chain_env, complete=True)
    (record,) = read_episode_results(chain_env.results_path)
    assert (record.chain_id, record.num_completed, record.subtask_steps) == (0, 5, (2, 2, 2, 2, 2))


def test_chain_ends_when_a_subtask_runs_out_of_steps(chain_env: CalvinEnv, tmp_path: Path) -> None:
    chain_env._oracle = ScriptedOracle()
    chain_env.results_path = tmp_path / "results.jsonl"
    chain_env.reset(seed=0)
    rewards = [_step(chain_env, complete=True)[1], _step(chain_env, complete=True)[1]]
    for _ in range(3):  # episode_length = 4 steps per subtask
        _, reward, terminated, truncated, info = _step(chain_env, complete=False)
        assert not (terminated or truncated)
        rewards.append(reward)
    _, reward, terminated, truncated, info = _step(chain_env, complete=False)
    rewards.append(reward)
    assert truncated and not terminated
    assert info == {"is_success": False, "num_completed": 2, "subtask_index": 2, "chain_id": 0}
    assert sum(rewards) == 2.0
    (record,) = read_episode_results(chain_env.results_path)
    assert record.num_completed == 2 and record.subtask_steps == (1, 1, 4)


def test_single_task_start_is_feasible_and_expert_succeeds() -> None:
    env = CalvinEnv("open_drawer", episode_length=200, **SMALL)
    env.reset(seed=3)
    assert is_feasible("open_drawer", env.simulation)
    assert env.task_description == EVAL_INSTRUCTIONS["open_drawer"]
    expert = ScriptedExpert(env.simulation, "open_drawer", np.random.default_rng(0))
    for _ in range(200):
        _, reward, terminated, truncated, info = env.step(expert.act())
        if terminated or truncated:
            break
    assert terminated and reward == 1.0 and info["is_success"] and info["num_completed"] == 1
    env.close()


def test_single_task_budget_truncates() -> None:
    env = CalvinEnv("turn_on_led", episode_length=3, **SMALL)
    env.reset(seed=0)
    results = [env.step(np.zeros(7)) for _ in range(3)]
    assert [r[3] for r in results] == [False, False, True]
    assert not any(r[4]["is_success"] for r in results)
    env.close()


@pytest.mark.slow
@pytest.mark.parametrize("task", ["place_in_slider", "unstack_block"])
def test_single_task_reset_prepares_tasks_that_need_earlier_tasks(task: str) -> None:
    env = CalvinEnv(task, **SMALL)
    env.reset(seed=0)
    assert is_feasible(task, env.simulation)
    env.close()


def test_sync_vector_env_steps_two_chains() -> None:
    fns = [partial(CalvinEnv, "lh_mtlc", chain_start=0, chain_stop=2, episode_length=4, **SMALL)] * 2
    vec = gym.vector.SyncVectorEnv(fns, autoreset_mode=gym.vector.AutoresetMode.NEXT_STEP)
    obs, info = vec.reset(seed=[0, 1], options={"chain_id": 1})
    assert obs["pixels"]["static"].shape == (2, 32, 32, 3)
    assert list(info["chain_id"]) == [1, 1]
    descriptions = vec.call("task_description")
    assert descriptions[0] == descriptions[1] == EVAL_INSTRUCTIONS[official_chains()[1].tasks[0]]
    obs, reward, terminated, truncated, _ = vec.step(np.zeros((2, 7), dtype=np.float32))
    assert reward.shape == (2,) and obs["agent_pos"].shape == (2, 15)
    vec.close()


def test_async_vector_env_with_two_forkserver_workers() -> None:
    chains = {cid: official_chains()[cid] for cid in range(3)}  # passed along: workers skip generating them
    fns = [
        partial(CalvinEnv, "lh_mtlc", chain_start=0, chain_stop=3, episode_length=4, chains=chains, **SMALL)
    ] * 2
    vec = gym.vector.AsyncVectorEnv(fns, context="forkserver")
    obs, info = vec.reset(seed=[0, 0])
    assert info["chain_id"][0] == info["chain_id"][1]
    for _ in range(3):
        obs, reward, terminated, truncated, _ = vec.step(np.zeros((2, 7), dtype=np.float32))
    np.testing.assert_array_equal(obs["agent_pos"][0], obs["agent_pos"][1])  # same chain, same actions
    assert len(vec.call("render")) == 2
    vec.close()


@pytest.mark.parametrize(
    ("action", "message"),
    [
        (np.zeros(6), r"shape \(7,\)"),
        (np.zeros((1, 7)), r"shape \(7,\)"),
        (np.array([0, 0, np.nan, 0, 0, 0, 1]), "action must be finite"),
        (np.array([0, 0, 0, np.inf, 0, 0, 1]), "action must be finite"),
    ],
)
def test_bad_actions_raise(chain_env: CalvinEnv, action: np.ndarray, message: str) -> None:
    chain_env.reset(seed=0)
    with pytest.raises(ValueError, match=message):
        chain_env.step(action)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"robot_obs": np.zeros(14)}, r"robot_obs must have shape \(15,\)"),
        ({"scene_obs": np.zeros((2, 24))}, r"scene_obs must have shape \(24,\)"),
        ({"scene_obs": np.full(24, np.nan)}, "scene_obs contains NaN"),
        ({"robot_obs": np.r_[np.zeros(14), np.inf]}, "robot_obs contains NaN or inf"),
        (
            {"robot_ob": np.zeros(15)},
            r"Unknown CalvinEnv reset option\(s\) \['robot_ob'\]; valid: chain_id, ",
        ),
    ],
)
def test_bad_reset_states_raise(chain_env: CalvinEnv, options: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        chain_env.reset(seed=0, options=options)


def test_reset_from_given_states() -> None:
    env = CalvinEnv("turn_off_led", episode_length=4, **SMALL)
    with pytest.raises(ValueError, match="Unknown CalvinEnv reset option"):
        env.reset(options={"chain_id": 3})  # chains exist only in lh_mtlc
    scene_obs = official_chains()[0].scene_obs.copy()
    obs, _ = env.reset(seed=0, options={"robot_obs": EVAL_ROBOT_OBS, "scene_obs": scene_obs})
    np.testing.assert_allclose(obs["environment_state"][:2], scene_obs[:2], atol=1e-3)
    np.testing.assert_allclose(obs["agent_pos"][7:14], EVAL_ROBOT_OBS[7:14], atol=1e-4)
    env.close()


def test_unknown_task_lists_the_valid_ones() -> None:
    with pytest.raises(ValueError, match="valid: 'lh_mtlc', rotate_red_block_right, .*push_into_drawer"):
        CalvinEnv("open_the_drawer")


def test_step_before_reset_raises() -> None:
    env = CalvinEnv("open_drawer", **SMALL)
    with pytest.raises(RuntimeError, match="before reset"):
        env.step(np.zeros(7))
    with pytest.raises(RuntimeError, match="before reset"):
        env.render()


@pytest.mark.calvin_assets
def test_chain_on_calvins_scene_d(calvin_assets_dir: Path) -> None:
    chain = official_chains()[0]
    env = CalvinEnv(
        "lh_mtlc", scene="calvin_D", assets_dir=calvin_assets_dir, chain_start=0, chain_stop=1, **SMALL
    )
    obs, info = env.reset(seed=0)
    np.testing.assert_allclose(obs["environment_state"], chain.scene_obs, atol=5e-3)  # blocks settle
    assert env.task_description == EVAL_INSTRUCTIONS[chain.tasks[0]]
    _, reward, terminated, truncated, info = env.step(np.zeros(7))
    assert (reward, terminated, truncated, info["num_completed"]) == (0.0, False, False, 0)
    env.close()


@pytest.mark.parametrize("task", ["open_drawer", "move_slider_left", "push_red_block_right", "unstack_block"])
def test_the_same_seed_gives_the_same_start_whatever_ran_before(task: str) -> None:
    """A fresh env's first reset(seed) equals the next one with that seed, and one after other episodes."""
    env = CalvinEnv(task, static_size=16, gripper_size=16, episode_length=20)
    try:
        first, _ = env.reset(seed=123)
        starts = [env.reset(seed=123)[0]]
        for seed in (3, 4):
            env.reset(seed=seed)
            for _ in range(10):
                env.step(env.action_space.sample())
        starts.append(env.reset(seed=123)[0])
        for again in starts:
            np.testing.assert_array_equal(again["agent_pos"], first["agent_pos"])
            np.testing.assert_array_equal(again["environment_state"], first["environment_state"])
            np.testing.assert_array_equal(again["pixels"]["static"], first["pixels"]["static"])
    finally:
        env.close()
