"""CALVIN's task oracle (spec 2.2/2.3) on synthetic info dicts: one firing and one near-miss case per task."""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lerobot_subgoalvla.calvin_vocab import TASK_NAMES
from lerobot_subgoalvla.envs.calvin.oracle.tasks import TASK_SPECS, TaskOracle

ROBOT, TABLE = 1, 2
BLOCK_UIDS = {"block_red": 3, "block_blue": 4, "block_pink": 5}
LINKS = {
    "base_link": -1,
    "button_link": 0,
    "switch_link": 1,
    "slide_link": 2,
    "drawer_link": 3,
    "led_link": 4,
    "light_link": 5,
    "plank_link": 6,
}
BASE, DRAWER, PLANK = LINKS["base_link"], LINKS["drawer_link"], LINKS["plank_link"]
COLORS = ("red", "blue", "pink")

Info = dict[str, Any]


def contact(body: int, link: int = -1) -> tuple:
    """A pybullet contact tuple: c[2] = other body, c[4] = other body's link."""
    return (
        0,
        0,
        body,
        -1,
        link,
        (0.0, 0.0, 0.0),
        (0.0, 0.0, 0.0),
        (0.0, 0.0, 1.0),
        0.0,
        1.0,
        0.0,
        (1, 0, 0),
        0.0,
        (0, 1, 0),
    )


def block(
    x: float = 0.0,
    z: float = 0.0,
    yaw_deg: float = 0.0,
    contacts: tuple = ((TABLE, BASE),),
    tilt_deg: float = 0.0,
    lin_vel: float = 0.0,
    ang_vel: float = 0.0,
) -> dict:
    orn = Rotation.from_euler("xyz", [tilt_deg, 0.0, yaw_deg], degrees=True).as_quat()
    return {
        "current_pos": np.array([x, 0.0, z]),
        "current_orn": orn,
        "current_lin_vel": np.full(3, lin_vel),
        "current_ang_vel": np.full(3, ang_vel),
        "contacts": [contact(*c) for c in contacts],
    }


def make_info(
    blocks: dict[str, dict] | None = None,
    robot_contacts: tuple = (),
    slide: float = 0.0,
    drawer: float = 0.0,
    lightbulb: int = 0,
    led: int = 0,
) -> Info:
    """A CALVIN info dict (spec 2.1); every block rests on the table's base unless overridden."""
    movable = {name: {**block(), "uid": uid} for name, uid in BLOCK_UIDS.items()}
    for name, state in (blocks or {}).items():
        movable[name] = {**state, "uid": BLOCK_UIDS[name]}
    return {
        "robot_info": {
            "tcp_pos": np.zeros(3),
            "tcp_orn": np.zeros(3),
            "gripper_opening_width": 0.08,
            "arm_joint_states": np.zeros(7),
            "gripper_action": 1,
            "uid": ROBOT,
            "contacts": [contact(*c) for c in robot_contacts],
        },
        "scene_info": {
            "fixed_objects": {"table": {"uid": TABLE, "links": dict(LINKS), "contacts": []}},
            "movable_objects": movable,
            "doors": {"base__slide": {"current_state": slide}, "base__drawer": {"current_state": drawer}},
            "lights": {"lightbulb": {"logical_state": lightbulb}, "led": {"logical_state": led}},
            "buttons": {"base__button": {"joint_state": 0.0, "logical_state": led}},
            "switches": {"base__switch": {"joint_state": 0.088 * lightbulb, "logical_state": lightbulb}},
        },
    }


Case = tuple[Info, Info, Info, Info]  # (start, end that fires, near-miss start, near-miss end)


def _rotate(color: str, sign: float) -> Case:
    name = f"block_{color}"
    start = make_info()
    return (
        start,
        make_info({name: block(yaw_deg=sign * 60.01)}),
        start,
        make_info({name: block(yaw_deg=sign * 59.99)}),
    )


def _push(color: str, sign: float) -> Case:
    name = f"block_{color}"  # start x = 0: a move of exactly 0.1 m is not enough (strict >)
    start = make_info({name: block(x=0.0)})
    return start, make_info({name: block(x=sign * 0.1001)}), start, make_info({name: block(x=sign * 0.1)})


def _lift(color: str, link: int, dz: float) -> Case:
    name = f"block_{color}"
    start = make_info({name: block(z=0.0, contacts=((TABLE, link),))})
    held = ((ROBOT, 10),)
    return (
        start,
        make_info({name: block(z=dz + 1e-4, contacts=held)}),
        start,
        make_info({name: block(z=dz, contacts=held)}),
    )


def _door(key: str, start: float, end: float, miss: float) -> Case:
    first = make_info(**{key: start})
    return first, make_info(**{key: end}), first, make_info(**{key: miss})


def _place(link: int, miss_link: int) -> Case:
    start = make_info({"block_red": block(z=0.1, contacts=((ROBOT, 10),))}, robot_contacts=((3, -1),))
    return (
        start,
        make_info({"block_red": block(contacts=((TABLE, link),))}),
        start,
        make_info({"block_red": block(contacts=((TABLE, miss_link),))}),
    )


def _light(key: str, before: int, after: int) -> Case:
    first = make_info(**{key: before})
    return first, make_info(**{key: after}), first, make_info(**{key: before})


def _stack() -> Case:
    on_blue = ((4, -1),)  # end velocity exactly 1 is not "at rest" (strict <)
    start = make_info()
    return (
        start,
        make_info({"block_red": block(contacts=on_blue, lin_vel=0.99, ang_vel=-0.99)}),
        start,
        make_info({"block_red": block(contacts=on_blue, lin_vel=1.0)}),
    )


def _unstack() -> Case:
    start = make_info({"block_red": block(contacts=((4, -1),), lin_vel=0.99)})
    fast_start = make_info(
        {"block_red": block(contacts=((4, -1),), ang_vel=1.0)}
    )  # start velocity must be < 1
    return start, make_info(), fast_start, make_info()


def _push_into() -> Case:
    # robot contact at the end is allowed (CALVIN's robot test is a no-op); a
    # robot contact at the start is not
    start = make_info({"block_pink": block(contacts=((TABLE, BASE),))})
    end = make_info({"block_pink": block(contacts=((TABLE, DRAWER), (ROBOT, 9)))})
    miss_start = make_info({"block_pink": block(contacts=((TABLE, BASE), (ROBOT, 9)))})
    return start, end, miss_start, end


CASES: dict[str, Callable[[], Case]] = {
    **{
        f"rotate_{c}_block_{side}": (lambda c=c, s=s: _rotate(c, s))
        for c in COLORS
        for side, s in (("right", -1.0), ("left", 1.0))
    },
    **{
        f"push_{c}_block_{side}": (lambda c=c, s=s: _push(c, s))
        for c in COLORS
        for side, s in (("right", 1.0), ("left", -1.0))
    },
    "move_slider_left": lambda: _door("slide", 0.0, 0.1501, 0.15),
    "move_slider_right": lambda: _door("slide", 0.15, -0.0001, 0.0),
    "open_drawer": lambda: _door("drawer", 0.0, 0.1201, 0.12),
    "close_drawer": lambda: _door("drawer", 0.12, -0.0001, 0.0),
    **{
        f"lift_{c}_block_{surface}": (lambda c=c, link=link, dz=dz: _lift(c, link, dz))
        for c in COLORS
        for surface, link, dz in (("table", BASE, 0.05), ("slider", PLANK, 0.03), ("drawer", DRAWER, 0.05))
    },
    "place_in_slider": lambda: _place(PLANK, DRAWER),
    "place_in_drawer": lambda: _place(DRAWER, PLANK),
    "stack_block": _stack,
    "unstack_block": _unstack,
    "turn_on_lightbulb": lambda: _light("lightbulb", 0, 1),
    "turn_off_lightbulb": lambda: _light("lightbulb", 1, 0),
    "turn_on_led": lambda: _light("led", 0, 1),
    "turn_off_led": lambda: _light("led", 1, 0),
    "push_into_drawer": _push_into,
}


def test_every_task_has_a_case_and_a_spec() -> None:
    assert set(CASES) == set(TASK_NAMES)
    assert tuple(TASK_SPECS) == TASK_NAMES == TaskOracle().task_names


@pytest.mark.parametrize("task", TASK_NAMES)
def test_task_fires_and_near_miss_does_not(task: str) -> None:
    oracle = TaskOracle()
    start, end, miss_start, miss_end = CASES[task]()
    assert oracle.is_completed(task, start, end)
    assert task in oracle.completed_tasks(start, end)
    assert not oracle.is_completed(task, miss_start, miss_end)
    assert task not in oracle.completed_tasks(miss_start, miss_end)


def test_nothing_fires_without_change() -> None:
    info = make_info()
    assert TaskOracle().completed_tasks(info, copy.deepcopy(info)) == set()


def test_completed_tasks_filter_and_accidental_tasks() -> None:
    start, end = make_info(slide=0.0, lightbulb=0), make_info(slide=0.2, lightbulb=1)
    oracle = TaskOracle()
    assert oracle.completed_tasks(start, end) == {"move_slider_left", "turn_on_lightbulb"}
    assert oracle.completed_tasks(start, end, tasks=["turn_on_lightbulb", "open_drawer"]) == {
        "turn_on_lightbulb"
    }


def test_rotate_quirks() -> None:
    oracle, start = TaskOracle(), make_info()
    in_air = make_info({"block_red": block(yaw_deg=-90, contacts=((ROBOT, 10),))})
    assert not oracle.is_completed("rotate_red_block_right", start, in_air)  # only the gripper touches it
    moved = make_info({"block_red": block(x=0.1001, yaw_deg=-90)})
    assert not oracle.is_completed("rotate_red_block_right", start, moved)  # moved > 0.1 m
    tilted = make_info({"block_red": block(yaw_deg=-90, tilt_deg=30.01)})
    assert not oracle.is_completed("rotate_red_block_right", start, tilted)  # needs |x| < 30 degrees
    slightly_tilted = make_info({"block_red": block(yaw_deg=-90, tilt_deg=29.99)})
    assert oracle.is_completed("rotate_red_block_right", start, slightly_tilted)
    # the delta is taken in the world frame: a block starting at yaw 170 and ending at -110 turned +80 degrees
    start_170 = make_info({"block_red": block(yaw_deg=170)})
    assert oracle.is_completed(
        "rotate_red_block_left", start_170, make_info({"block_red": block(yaw_deg=-110)})
    )


def test_place_requires_block_held_at_start() -> None:
    on_plank = make_info({"block_red": block(contacts=((TABLE, PLANK),))})
    # gripper touches the red block, but the block still rests on the table: not "held in the air"
    resting = make_info(
        {"block_red": block(contacts=((ROBOT, 10), (TABLE, BASE)))}, robot_contacts=((3, -1),)
    )
    assert not TaskOracle().is_completed("place_in_slider", resting, on_plank)
    # the robot touching a non-block body (the table) at the start is not a held block either
    touching_table = make_info({"block_red": block(contacts=((ROBOT, 10),))}, robot_contacts=((TABLE, BASE),))
    assert not TaskOracle().is_completed("place_in_slider", touching_table, on_plank)


def test_push_requires_same_support() -> None:
    start = make_info({"block_blue": block(x=0.0, contacts=((TABLE, BASE),))})
    lifted = make_info({"block_blue": block(x=0.2, contacts=((ROBOT, 10),))})
    other_support = make_info({"block_blue": block(x=0.2, contacts=((TABLE, DRAWER),))})
    oracle = TaskOracle()
    assert not oracle.is_completed("push_blue_block_right", start, lifted)
    assert not oracle.is_completed("push_blue_block_right", start, other_support)


def test_unknown_task_lists_valid_ones() -> None:
    info = make_info()
    with pytest.raises(ValueError, match="valid tasks: rotate_red_block_right"):
        TaskOracle().is_completed("open_the_fridge", info, info)
    with pytest.raises(ValueError, match="open_the_fridge"):
        TaskOracle().completed_tasks(info, info, tasks=["open_the_fridge"])


def test_malformed_info_names_the_missing_key() -> None:
    info = make_info()
    broken = copy.deepcopy(info)
    del broken["scene_info"]["doors"]
    with pytest.raises(ValueError, match="scene_info.doors"):
        TaskOracle().is_completed("open_drawer", info, broken)


def test_oracle_reads_the_simulator_info() -> None:
    """The seam with CalvinSimulation.get_info(): teleport doors, lights and blocks between two infos."""
    from lerobot_subgoalvla.envs.calvin.evaluation.chains import EVAL_ROBOT_OBS, scene_obs_for_state
    from lerobot_subgoalvla.envs.calvin.sim.simulation import CalvinSimulation

    state = {
        "led": 0,
        "lightbulb": 0,
        "slider": "right",
        "drawer": "closed",
        "red_block": "table",
        "blue_block": "slider_left",
        "pink_block": "table",
        "grasped": 0,
    }
    start_obs = scene_obs_for_state(state)
    end_obs = start_obs.copy()
    end_obs[[0, 1, 3, 4, 5]] = [0.2, 0.2, 0.088, 1.0, 1.0]  # slider left, drawer open, both lights on
    end_obs[6] += 0.12  # red block 12 cm to the right (+x)
    end_obs[23] -= np.pi / 2  # pink block turned 90 degrees clockwise
    idle = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    infos = []
    with CalvinSimulation(cameras=False) as sim:
        for obs in (start_obs, end_obs):
            sim.reset(EVAL_ROBOT_OBS, obs)
            for _ in range(5):
                sim.step(idle)
            infos.append(sim.get_info())
    assert TaskOracle().completed_tasks(*infos) == {
        "move_slider_left",
        "open_drawer",
        "turn_on_lightbulb",
        "turn_on_led",
        "push_red_block_right",
        "rotate_pink_block_right",
    }
    assert TaskOracle().completed_tasks(infos[0], infos[0]) == set()
