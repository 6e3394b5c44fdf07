"""CALVIN's LH-MTLC chain generator against the check values of docs/calvin.md 4.1-4.2, and its CLI."""

from __future__ import annotations

import json
import logging
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from lerobot_subgoalvla.envs.calvin.evaluation import chains
from lerobot_subgoalvla.envs.calvin.evaluation.chains import (
    EVAL_ROBOT_OBS,
    TASK_CATEGORIES,
    Chain,
    apply_task,
    fnv1_32,
    generate_chains,
    initial_states,
    is_valid_sequence,
    load_chains,
    main,
    scene_obs_for_state,
    state_seed,
)

#: Spec 4.1's task list order (full names), which fixes what RandomState(i).choice(T, 5) picks.
SPEC_TASK_ORDER = (
    [
        f"{verb}_{c}_block_{side}"
        for verb in ("rotate", "push")
        for c in ("red", "blue", "pink")
        for side in ("right", "left")
    ]
    + ["move_slider_left", "move_slider_right", "open_drawer", "close_drawer"]
    + [f"lift_{c}_block_{s}" for c in ("red", "blue", "pink") for s in ("table", "slider", "drawer")]
    + [
        "place_in_slider",
        "place_in_drawer",
        "stack_block",
        "unstack_block",
        "turn_on_lightbulb",
        "turn_off_lightbulb",
        "turn_on_led",
        "turn_off_led",
        "push_into_drawer",
    ]
)

CHAIN0_STATE = {
    "led": 1,
    "lightbulb": 1,
    "slider": "left",
    "drawer": "open",
    "red_block": "slider_left",
    "blue_block": "table",
    "pink_block": "slider_right",
    "grasped": 0,
}
CHAIN0_TASKS = (
    "rotate_blue_block_right",
    "move_slider_right",
    "lift_red_block_slider",
    "place_in_slider",
    "turn_off_lightbulb",
)

#: Spec 4.1: task frequencies over all 5000 subtasks of the official 1000 chains.
SPEC_FREQUENCIES = {
    "place_in_slider": 398,
    "open_drawer": 379,
    "move_slider_right": 317,
    "move_slider_left": 284,
    "close_drawer": 250,
    "stack_block": 220,
    "place_in_drawer": 208,
    "lift_blue_block_table": 205,
    "turn_on_lightbulb": 202,
    "lift_red_block_table": 199,
    "turn_on_led": 195,
    "lift_pink_block_table": 187,
    "turn_off_led": 185,
    "turn_off_lightbulb": 171,
    "lift_red_block_slider": 157,
    "lift_pink_block_slider": 156,
    "lift_blue_block_slider": 151,
    "push_into_drawer": 138,
    "unstack_block": 81,
    "lift_red_block_drawer": 23,
    "lift_blue_block_drawer": 23,
    "lift_pink_block_drawer": 17,
}


@pytest.fixture(scope="module")
def official_chains() -> list[Chain]:
    return generate_chains(1000)


def test_fnv1_check_values() -> None:
    assert fnv1_32(b"hello world") == 2805756500
    assert fnv1_32("hello world".encode("utf-16-le")) == 3799943344
    assert state_seed(CHAIN0_STATE) == 2138410836
    # numpy ints print differently in CPython; the seed must not depend on the value type
    assert (
        state_seed({k: np.int64(v) if isinstance(v, int) else v for k, v in CHAIN0_STATE.items()})
        == 2138410836
    )


def test_initial_states() -> None:
    states = initial_states()
    assert len(states) == 192
    assert states[0] == {
        "led": 0,
        "lightbulb": 0,
        "slider": "right",
        "drawer": "closed",
        "red_block": "table",
        "blue_block": "table",
        "pink_block": "slider_right",
        "grasped": 0,
    }
    for state in states:
        blocks = [state[f"{c}_block"] for c in ("red", "blue", "pink")]
        assert blocks.count("table") in (1, 2)
        assert blocks.count("slider_left") < 2 and blocks.count("slider_right") < 2


def test_task_order_and_categories() -> None:
    assert list(chains.SYMBOLIC_TASKS) == SPEC_TASK_ORDER
    assert len(set(TASK_CATEGORIES.values())) == 11
    assert TASK_CATEGORIES["push_into_drawer"] == 9 and TASK_CATEGORIES["place_in_drawer"] == 7


@pytest.mark.parametrize("seed", [0, 1, 191])
def test_vectorised_draws_equal_numpy_choice(seed: int) -> None:
    rs = np.random.RandomState(seed)
    expected = np.array([rs.choice(34, size=5, replace=False) for _ in range(1500)])
    rs = np.random.RandomState(seed)
    got = np.concatenate([chains._draw_choices(rs, 1000), chains._draw_choices(rs, 500)])
    np.testing.assert_array_equal(got, expected)


def test_vectorised_validity_equals_symbolic_check(official_chains: list[Chain]) -> None:
    table = chains._TransitionTable()
    names = list(chains.SYMBOLIC_TASKS)
    state = initial_states()[7]
    draws = chains._draw_choices(np.random.RandomState(7), 3000)
    accepted = [c for c in official_chains if c.initial_state == state]
    draws = np.concatenate([draws, [[names.index(t) for t in c.tasks] for c in accepted]])
    reference = [is_valid_sequence(state, [names[k] for k in row]) for row in draws]
    np.testing.assert_array_equal(table.valid(state, draws), reference)
    assert sum(reference) >= len(accepted) > 0


def test_chain_zero(official_chains: list[Chain]) -> None:
    chain = official_chains[0]
    assert chain.initial_state == CHAIN0_STATE
    assert chain.tasks == CHAIN0_TASKS


def test_task_frequencies(official_chains: list[Chain]) -> None:
    counts = Counter(task for chain in official_chains for task in chain.tasks)
    assert sum(counts.values()) == 5000
    assert {task: counts[task] for task in SPEC_FREQUENCIES} == SPEC_FREQUENCIES
    rotate_push = {
        t: n for t, n in counts.items() if t.startswith(("rotate_", "push_")) and t != "push_into_drawer"
    }
    assert len(rotate_push) == 12 and all(57 <= n <= 79 for n in rotate_push.values())
    assert min(rotate_push.values()) == 57 and max(rotate_push.values()) == 79


def test_chains_per_state_categories_and_preconditions(official_chains: list[Chain]) -> None:
    states = initial_states()
    index = {tuple(s.values()): i for i, s in enumerate(states)}
    per_state = Counter(index[tuple(c.initial_state.values())] for c in official_chains)
    assert [per_state[i] for i in range(192)] == [6] * 40 + [5] * 152
    for chain in official_chains:
        assert len({TASK_CATEGORIES[t] for t in chain.tasks}) == 5
        state = chain.initial_state
        for task in chain.tasks:
            state = apply_task(state, task)
            assert state is not None, (chain.tasks, task)


def test_scene_obs_of_chain_zero(official_chains: list[Chain]) -> None:
    obs = official_chains[0].scene_obs
    assert obs.shape == (24,)
    np.testing.assert_array_equal(obs[:6], [0.28, 0.22, 0.0, 0.088, 1.0, 1.0])
    # independent derivation of spec 4.2: RandomState(h) shuffles the two table slots, then draws 3 yaws
    rs = np.random.RandomState(2138410836)
    table = [
        np.array([0.0500000896, -0.120000177, 0.459990009]),
        np.array([0.229995412, -0.11999514, 0.45999001]),
    ]
    rs.shuffle(table)
    yaws = [rs.uniform(np.pi / 2 - np.pi / 8, np.pi / 2 + np.pi / 8) for _ in range(3)]
    np.testing.assert_allclose(obs[6:9], [-0.240851662, 0.0924044687, 0.460990009])  # red: slider_left
    np.testing.assert_allclose(obs[12:15], table[0])  # blue on the table, red is not: first shuffled slot
    np.testing.assert_allclose(obs[18:21], [0.070341633, 0.0924044687, 0.460990009])  # pink: slider_right
    np.testing.assert_array_equal(obs[[11, 17, 23]], yaws)
    np.testing.assert_array_equal(obs[[9, 10, 15, 16, 21, 22]], 0.0)


def test_scene_obs_is_a_function_of_the_state(official_chains: list[Chain]) -> None:
    by_state: dict[tuple, np.ndarray] = {}
    for chain in official_chains:
        key = tuple(chain.initial_state.values())
        by_state.setdefault(key, chain.scene_obs)
        np.testing.assert_array_equal(chain.scene_obs, by_state[key])
    assert len(by_state) == 192
    blue_on_table = {
        "led": 0,
        "lightbulb": 0,
        "slider": "right",
        "drawer": "closed",
        "red_block": "table",
        "blue_block": "table",
        "pink_block": "slider_left",
        "grasped": 0,
    }
    obs = scene_obs_for_state(blue_on_table)
    assert not np.allclose(obs[6:9], obs[12:15])  # red and blue take the two different table slots
    assert obs[0] == 0.0 and obs[1] == 0.0 and obs[3] == 0.0


def test_eval_robot_obs() -> None:
    assert EVAL_ROBOT_OBS.shape == (15,) and EVAL_ROBOT_OBS[14] == 1.0 and EVAL_ROBOT_OBS[6] == 0.07999963
    with pytest.raises(ValueError):
        EVAL_ROBOT_OBS[0] = 1.0


def test_small_chain_counts() -> None:
    chains = generate_chains(10)
    assert len(chains) == 10
    with pytest.raises(ValueError, match="num_chains"):
        generate_chains(0)


def test_cli_writes_json(tmp_path: Path) -> None:
    out = tmp_path / "sub" / "chains.json"
    assert main(["--num-chains", "10", "--output", str(out), "--start", "3", "--stop", "7"]) == 0
    entries = json.loads(out.read_text())
    assert [e["chain_id"] for e in entries] == [3, 4, 5, 6]
    assert all(set(e) == {"chain_id", "initial_state", "tasks", "scene_obs"} for e in entries)
    expected = generate_chains(10)
    loaded = load_chains(out)
    for chain_id in range(3, 7):
        assert loaded[chain_id].tasks == expected[chain_id].tasks
        np.testing.assert_array_equal(loaded[chain_id].scene_obs, expected[chain_id].scene_obs)
    assert not list(out.parent.glob(".*tmp"))  # no temporary file left behind


@pytest.mark.parametrize(
    "argv",
    [["--start", "5", "--stop", "3"], ["--num-chains", "0"], ["--stop", "11"], ["--num-chains", "ten"], []],
)
def test_cli_bad_args(tmp_path: Path, caplog: pytest.LogCaptureFixture, argv: list[str]) -> None:
    out = tmp_path / "chains.json"
    full = (["--output", str(out)] if argv else []) + ["--num-chains", "10", *argv]
    with caplog.at_level(logging.ERROR), pytest.raises(SystemExit) as exit_info:
        main(full)
    assert exit_info.value.code == 1
    errors = [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1 and "\n" not in errors[0].getMessage()
    assert not out.exists()


def test_load_chains_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="subgoalvla-calvin-chains"):
        load_chains(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text('[{"chain_id": 0, "tasks": ["open_drawer"]}]')
    with pytest.raises(ValueError, match=r"bad\.json"):
        load_chains(bad)
