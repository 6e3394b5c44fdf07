"""record_segment's language windows: where a window that follows another task starts (issue 25).

A CALVIN chain hands the next subtask over at the first step the previous subtask's oracle fires; by default
the generator starts the next window only after the previous script's retreat, so no window starts in a
hand-over state. These tests run ``record_segment`` on a fake simulation with a scripted fake expert and
oracle (no pybullet), so the frame bookkeeping is checked exactly and fast.
"""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_subgoalvla.datasets_conversion import calvin_play

SCRIPT_STEPS = 6  # every fake task runs six steps
FIRES_AFTER = 3  # and its oracle holds from its third step on (the real expert then releases and retreats)
NEVER_FIRES = "turn_on_led"  # a failed attempt


class FakeSim:
    """A counter for a simulation: state t is the number of steps taken; images are constant."""

    def __init__(self) -> None:
        self.t = 0

    def robot_obs(self) -> np.ndarray:
        return np.full(15, float(self.t))

    def scene_obs(self) -> np.ndarray:
        return np.full(24, float(self.t))

    def render_cameras(self) -> dict[str, np.ndarray]:
        return {"static": np.zeros((4, 4, 3), np.uint8), "gripper": np.zeros((2, 2, 3), np.uint8)}

    def step(self, action: np.ndarray) -> None:
        self.t += 1

    def get_info(self) -> dict[str, int]:
        return {"t": self.t}


class FakeOracle:
    def is_completed(self, task: str, start: dict, end: dict) -> bool:
        return task != NEVER_FIRES and end["t"] - start["t"] >= FIRES_AFTER


@pytest.fixture
def fake_play(monkeypatch: pytest.MonkeyPatch):
    """Patch the expert, feasibility, start sampler and oracle that ``record_segment`` imports; the tasks are
    played in the order given (only the planned next task is feasible, so the rng's choice is forced)."""
    from lerobot_subgoalvla.envs.calvin.expert import scripted_expert, start_states
    from lerobot_subgoalvla.envs.calvin.oracle import tasks as oracle_tasks

    def play(plan: list[str], **kwargs) -> calvin_play.PlaySegment:
        started: list[str] = []

        class FakeExpert:
            def __init__(self, sim: FakeSim, task: str, rng: np.random.Generator) -> None:
                started.append(task)
                self.done, self.steps = False, 0

            def act(self) -> np.ndarray:
                if self.steps == SCRIPT_STEPS:
                    self.done = True  # like ScriptedExpert: the call after the last action ends the script
                else:
                    self.steps += 1
                return np.zeros(7)

        def feasible(name: str, sim: FakeSim) -> bool:  # the last task stays feasible: no recovery motion
            return name == plan[min(len(started), len(plan) - 1)]

        monkeypatch.setattr(scripted_expert, "ScriptedExpert", FakeExpert)
        monkeypatch.setattr(scripted_expert, "is_feasible", feasible)
        monkeypatch.setattr(start_states, "sample_start_state", lambda task, sim, rng: None)
        monkeypatch.setattr(oracle_tasks, "TaskOracle", FakeOracle)
        segment = calvin_play.record_segment(
            FakeSim(), len(plan), np.random.default_rng(0), tasks=tuple(dict.fromkeys(plan)),
            first_task=plan[0], **kwargs,
        )  # fmt: skip
        assert started == plan
        return segment

    return play


PLAN = ["open_drawer", "close_drawer", NEVER_FIRES, "move_slider_left"]


def _starts_ends(segment: calvin_play.PlaySegment) -> list[tuple[int, int, str]]:
    return [(start, end, task) for start, end, _, task in segment.windows]


def test_default_windows_start_where_the_expert_starts_the_task(fake_play) -> None:
    segment = fake_play(PLAN)
    # tasks span frames 0-6, 6-12, 12-18 (failed, no window), 18-24 (state 24 is not saved: end clamped)
    assert _starts_ends(segment) == [
        (0, 6, "open_drawer"),
        (6, 12, "close_drawer"),
        (18, 23, "move_slider_left"),
    ]


def test_windows_from_completion_start_where_the_previous_task_fired(fake_play) -> None:
    segment = fake_play(PLAN, windows_from_completion=True)
    # close_drawer's window starts at state 3, where open_drawer's oracle first held (a chain's hand-over);
    # after the failed attempt the next window starts with its own task, as by default
    assert _starts_ends(segment) == [
        (0, 6, "open_drawer"),
        (3, 12, "close_drawer"),
        (18, 23, "move_slider_left"),
    ]
    # only the labels move: the recorded frames are those of the default
    reference = fake_play(PLAN)
    for key, values in reference.frames.items():
        np.testing.assert_array_equal(segment.frames[key], values, err_msg=key)
    assert (segment.attempted, segment.completed) == (reference.attempted, reference.completed)


def test_the_generator_flag_reaches_the_recorded_options() -> None:
    from lerobot_subgoalvla.datasets_conversion.generate_calvin import GeneratorOptions, parse_args

    args = vars(
        parse_args(["--output", "x", "--num-tasks", "16", "--seed", "0", "--windows-from-completion"])
    )
    args.pop("output"), args.pop("workers")
    assert GeneratorOptions(**args).windows_from_completion
    assert not GeneratorOptions(num_tasks=16, seed=0).windows_from_completion  # the default data is unchanged


def test_next_task_weights_shift_the_draw_towards_the_rarer_tasks() -> None:
    from lerobot_subgoalvla.calvin_vocab import FIXTURE_TASKS

    feasible = [*FIXTURE_TASKS, "stack_block", "lift_red_block_table"]
    weights = dict.fromkeys(FIXTURE_TASKS, 0.2)
    rng = np.random.default_rng(0)
    draws = [calvin_play.draw_next_task(feasible, rng, weights) for _ in range(4000)]
    block_share = np.mean([task not in FIXTURE_TASKS for task in draws])
    assert block_share == pytest.approx(2 / (2 + 8 * 0.2), abs=0.03)  # 56 %, uniform would give 20 %
    # without weights the draw is rng.choice's own, so data generated before the option stays the same
    a, b = np.random.default_rng(1), np.random.default_rng(1)
    assert [calvin_play.draw_next_task(feasible, a, None) for _ in range(50)] == [
        str(b.choice(feasible)) for _ in range(50)
    ]


def test_the_fixture_weight_reaches_the_draw_and_is_validated() -> None:
    from lerobot_subgoalvla.calvin_vocab import FIXTURE_TASKS
    from lerobot_subgoalvla.datasets_conversion.generate_calvin import GeneratorOptions, parse_args

    args = vars(parse_args(["--output", "x", "--num-tasks", "16", "--seed", "0", "--fixture-weight", "0.25"]))
    args.pop("output"), args.pop("workers")
    assert GeneratorOptions(**args).task_weights() == dict.fromkeys(FIXTURE_TASKS, 0.25)
    assert GeneratorOptions(num_tasks=16, seed=0).task_weights() is None
    with pytest.raises(ValueError, match=r"--fixture-weight must be > 0"):
        GeneratorOptions(num_tasks=16, seed=0, fixture_weight=0.0)
