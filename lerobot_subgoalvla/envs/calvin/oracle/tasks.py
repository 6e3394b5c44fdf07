"""CALVIN's success oracle: which of the 34 tasks were completed between two info snapshots.

Clean-room re-implementation of calvin_env ``envs/tasks.py`` + ``conf/tasks/new_playtable_tasks.yaml``
(docs/calvin.md sections 2.1-2.3; identical in calvin_env ``1431a46`` and ``797142c``). Every predicate,
threshold and strict/non-strict comparison is CALVIN's, quirks included, because benchmark numbers depend on
them:

- ``rotate`` measures the world-frame delta rotation ``R_end * R_start^-1`` as SciPy ``as_euler("xyz",
  degrees=True)``; the block may move at most 0.1 m and must rest on something other than the gripper.
- ``place`` only fires when the block was already held in the air (touching only the robot) at the start of
  the subtask, and the robot touched exactly that one body.
- ``push_into`` intends "the robot touches the block neither at start nor at end", but CALVIN compares the
  robot uid with a set of ``(body, link)`` tuples, so that test is a no-op: robot contact at the end is
  allowed (at the start it is excluded by requiring exactly one contact, the table's base).

Inputs are the info dicts of ``CalvinSimulation.get_info()`` (spec 2.1). A contact tuple ``c`` is one entry of
pybullet's ``getContactPoints``: ``c[2]`` is the other body's uid, ``c[4]`` the other body's link index.

The task table (:data:`TASK_SPECS`) maps each task name to one of nine predicates plus its parameters, as
CALVIN's yaml does; :class:`TaskOracle` evaluates it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from lerobot_subgoalvla.calvin_vocab import TASK_NAMES, check_task_name

Info = Mapping[str, Any]
Contact = Sequence[Any]

#: The fixed body every CALVIN surface belongs to (spec 3.2: one multi-link table body).
TABLE = "table"
#: Blocks in CALVIN's ``movable_objects`` naming (scene D order).
BLOCKS: tuple[str, ...] = ("block_red", "block_blue", "block_pink")


# --------------------------------------------------------------------------------------------- info access
def _lookup(info: Info, *path: str) -> Any:
    """``info[path[0]][path[1]]...`` with a one-line error naming the missing key (spec 2.1 structure)."""
    node: Any = info
    for depth, key in enumerate(path):
        if not isinstance(node, Mapping) or key not in node:
            where = ".".join(path[: depth + 1])
            raise ValueError(
                f"Info dict lacks {where!r}; the oracle expects CalvinSimulation.get_info()'s structure "
                "(docs/calvin.md 2.1)"
            )
        node = node[key]
    return node


def _robot_uid(info: Info) -> int:
    return int(_lookup(info, "robot_info", "uid"))


def _block(info: Info, name: str) -> Mapping[str, Any]:
    return _lookup(info, "scene_info", "movable_objects", name)


def _contact_bodies(contacts: Iterable[Contact]) -> set[int]:
    """Uids of the bodies in contact (``c[2]``)."""
    return {int(c[2]) for c in contacts}


def _contact_links(contacts: Iterable[Contact]) -> set[tuple[int, int]]:
    """``(body uid, link index)`` pairs in contact (``c[2]``, ``c[4]``)."""
    return {(int(c[2]), int(c[4])) for c in contacts}


def _surface(info: Info, link: str) -> tuple[int, int]:
    """``(table uid, link index)`` of a named table link, read from the info dict as CALVIN does."""
    table = _lookup(info, "scene_info", "fixed_objects", TABLE)
    return int(table["uid"]), int(_lookup(table, "links", link))


def _below(values: Any, limit: float) -> bool:
    return bool(np.all(np.abs(np.asarray(values, dtype=np.float64)) < limit))


# -------------------------------------------------------------------------------------------- predicates
def rotate(
    start: Info,
    end: Info,
    *,
    block: str,
    degrees: float,
    xy_threshold: float = 30.0,
    z_threshold: float = 180.0,
    max_move: float = 0.1,
) -> bool:
    """Block turned about world z by more than ``degrees`` (sign = direction), spec 2.2 ``rotate``.

    ``degrees`` > 0 is counter-clockwise seen from above ("left"), < 0 clockwise ("right").
    """
    s, e = _block(start, block), _block(end, block)
    delta = Rotation.from_quat(e["current_orn"]) * Rotation.from_quat(s["current_orn"]).inv()
    x, y, z = delta.as_euler("xyz", degrees=True)
    if np.linalg.norm(np.asarray(e["current_pos"]) - np.asarray(s["current_pos"])) > max_move:
        return False
    if not _contact_bodies(e["contacts"]) - {_robot_uid(start)}:
        return False  # held in the air by the gripper only
    tilt_ok = abs(x) < xy_threshold and abs(y) < xy_threshold
    if degrees > 0:
        return bool(degrees < z < z_threshold and tilt_ok)
    return bool(degrees > z > -z_threshold and tilt_ok)


def push(start: Info, end: Info, *, block: str, dx: float) -> bool:
    """Block slid along world x by more than ``dx`` (sign = direction) on the same support, spec 2.2
    ``push``."""
    s, e = _block(start, block), _block(end, block)
    robot = _robot_uid(start)
    start_support = {pair for pair in _contact_links(s["contacts"]) if pair[0] != robot}
    end_support = {pair for pair in _contact_links(e["contacts"]) if pair[0] != robot}
    if not (start_support and end_support and start_support <= end_support):
        return False
    moved = float(e["current_pos"][0]) - float(s["current_pos"][0])
    return moved > dx if dx > 0 else moved < dx


def move_door(start: Info, end: Info, *, joint: str, threshold: float) -> bool:
    """Joint moved by more than ``threshold`` metres (sign = direction), CALVIN's ``move_door_rel``."""
    moved = float(_lookup(end, "scene_info", "doors", joint, "current_state")) - float(
        _lookup(start, "scene_info", "doors", joint, "current_state")
    )
    return 0 < threshold < moved or 0 > threshold > moved


def lift(start: Info, end: Info, *, block: str, dz: float, surface_link: str) -> bool:
    """Block raised by more than ``dz`` while touching only the robot, having rested on ``surface_link``."""
    s, e = _block(start, block), _block(end, block)
    end_bodies = _contact_bodies(e["contacts"])
    return (
        float(e["current_pos"][2]) - float(s["current_pos"][2]) > dz
        and _robot_uid(start) in end_bodies
        and len(end_bodies) == 1
        and _surface(start, surface_link) in _contact_links(s["contacts"])
    )


def place(start: Info, end: Info, *, dest_link: str) -> bool:
    """The block held (in the air) at the start now rests on ``dest_link`` and the robot let go of it."""
    robot = _robot_uid(start)
    held = _contact_bodies(_lookup(start, "robot_info", "contacts"))
    if len(held) != 1:
        return False
    (obj_uid,) = held
    if obj_uid in _contact_bodies(_lookup(end, "robot_info", "contacts")):
        return False
    movable = _lookup(start, "scene_info", "movable_objects")
    names = [name for name, obj in movable.items() if int(obj["uid"]) == obj_uid]
    if len(names) != 1:
        return False  # the robot touched something that is not a block
    start_bodies = _contact_bodies(movable[names[0]]["contacts"])
    end_links = _contact_links(_block(end, names[0])["contacts"])
    return robot in start_bodies and len(start_bodies) == 1 and _surface(end, dest_link) in end_links


def _block_uids(info: Info) -> set[int]:
    return {int(obj["uid"]) for obj in _lookup(info, "scene_info", "movable_objects").values()}


def stack(start: Info, end: Info, *, max_vel: float = 1.0) -> bool:
    """Some block that touched no block now rests only on blocks, nearly at rest (end velocities <
    max_vel)."""
    blocks = _block_uids(start)
    for name in _lookup(start, "scene_info", "movable_objects"):
        s, e = _block(start, name), _block(end, name)
        before, after = _contact_bodies(s["contacts"]), _contact_bodies(e["contacts"])
        if (
            not blocks & before
            and blocks & after
            and not after - blocks
            and _below(e["current_lin_vel"], max_vel)
            and _below(e["current_ang_vel"], max_vel)
        ):
            return True
    return False


def unstack(start: Info, end: Info, *, max_vel: float = 1.0) -> bool:
    """Some block that rested only on blocks (slowly, start velocities < max_vel) now touches no block."""
    blocks = _block_uids(start)
    for name in _lookup(start, "scene_info", "movable_objects"):
        s, e = _block(start, name), _block(end, name)
        before, after = _contact_bodies(s["contacts"]), _contact_bodies(e["contacts"])
        if (
            blocks & before
            and not before - blocks
            and not blocks & after
            and _below(s["current_lin_vel"], max_vel)
            and _below(s["current_ang_vel"], max_vel)
        ):
            return True
    return False


def toggle_light(start: Info, end: Info, *, light: str, before: int, after: int) -> bool:
    """Light's logical state went from ``before`` (at the start) to ``after`` (now)."""
    return bool(
        _lookup(start, "scene_info", "lights", light, "logical_state") == before
        and _lookup(end, "scene_info", "lights", light, "logical_state") == after
    )


def push_into(start: Info, end: Info, *, blocks: tuple[str, ...], src_link: str, dest_link: str) -> bool:
    """Any of ``blocks`` rested only on ``src_link`` at the start and touches ``dest_link`` now.

    CALVIN's extra "robot touches neither at start nor end" clause is a no-op (see module docstring) and is
    therefore not evaluated.
    """
    src, dest = _surface(start, src_link), _surface(end, dest_link)
    for name in blocks:
        start_links = _contact_links(_block(start, name)["contacts"])
        if (
            len(start_links) == 1
            and src in start_links
            and dest in _contact_links(_block(end, name)["contacts"])
        ):
            return True
    return False


# ------------------------------------------------------------------------------------------- task table
@dataclass(frozen=True)
class TaskSpec:
    """One row of CALVIN's task yaml: a predicate and its parameters."""

    predicate: Callable[..., bool]
    params: Mapping[str, Any]

    def __call__(self, start: Info, end: Info) -> bool:
        return bool(self.predicate(start, end, **self.params))


def _task_table() -> dict[str, TaskSpec]:
    """CALVIN's ``new_playtable_tasks.yaml`` (spec 2.3), one row per task."""
    rows: list[tuple[str, Callable[..., bool], dict[str, Any]]] = []
    for color in ("red", "blue", "pink"):
        for side, degrees in (("right", -60.0), ("left", 60.0)):
            rows.append(
                (f"rotate_{color}_block_{side}", rotate, {"block": f"block_{color}", "degrees": degrees})
            )
    for color in ("red", "blue", "pink"):
        for side, dx in (("right", 0.1), ("left", -0.1)):
            rows.append((f"push_{color}_block_{side}", push, {"block": f"block_{color}", "dx": dx}))
    rows += [
        ("move_slider_left", move_door, {"joint": "base__slide", "threshold": 0.15}),
        ("move_slider_right", move_door, {"joint": "base__slide", "threshold": -0.15}),
        ("open_drawer", move_door, {"joint": "base__drawer", "threshold": 0.12}),
        ("close_drawer", move_door, {"joint": "base__drawer", "threshold": -0.12}),
    ]
    for color in ("red", "blue", "pink"):
        for surface, dz, link in (
            ("table", 0.05, "base_link"),
            ("slider", 0.03, "plank_link"),
            ("drawer", 0.05, "drawer_link"),
        ):
            rows.append(
                (
                    f"lift_{color}_block_{surface}",
                    lift,
                    {"block": f"block_{color}", "dz": dz, "surface_link": link},
                )
            )
    rows += [
        ("place_in_slider", place, {"dest_link": "plank_link"}),
        ("place_in_drawer", place, {"dest_link": "drawer_link"}),
        ("stack_block", stack, {"max_vel": 1.0}),
        ("unstack_block", unstack, {"max_vel": 1.0}),
        ("turn_on_lightbulb", toggle_light, {"light": "lightbulb", "before": 0, "after": 1}),
        ("turn_off_lightbulb", toggle_light, {"light": "lightbulb", "before": 1, "after": 0}),
        ("turn_on_led", toggle_light, {"light": "led", "before": 0, "after": 1}),
        ("turn_off_led", toggle_light, {"light": "led", "before": 1, "after": 0}),
        (
            "push_into_drawer",
            push_into,
            {"blocks": BLOCKS, "src_link": "base_link", "dest_link": "drawer_link"},
        ),
    ]
    table = {name: TaskSpec(predicate, MappingProxyType(params)) for name, predicate, params in rows}
    return {name: table[name] for name in TASK_NAMES}  # CALVIN's task-id order


#: Task name -> predicate + parameters, in CALVIN's task-id order (spec 2.3).
TASK_SPECS: Mapping[str, TaskSpec] = MappingProxyType(_task_table())


class TaskOracle:
    """Decides which CALVIN tasks were completed between a subtask's start info and the current info.

    Mirrors calvin_env's ``Tasks.get_task_info`` / ``get_task_info_for_set`` (spec 2.2). In the LH-MTLC
    rollout a subtask succeeds at the first step where ``is_completed(task, start_info, info)`` is true (spec
    4.3).
    """

    @property
    def task_names(self) -> tuple[str, ...]:
        """The 34 task names in CALVIN's id order."""
        return tuple(TASK_SPECS)

    def is_completed(self, task: str, start_info: Info, end_info: Info) -> bool:
        """Whether ``task`` is completed between ``start_info`` and ``end_info``.

        Raises:
            ValueError: ``task`` is not a CALVIN task, or an info dict lacks a key the predicate reads.
        """
        return TASK_SPECS[check_task_name(task)](start_info, end_info)

    def completed_tasks(
        self, start_info: Info, end_info: Info, tasks: Iterable[str] | None = None
    ) -> set[str]:
        """All completed tasks, or only those among ``tasks`` when given (CALVIN's ``task_filter``)."""
        names = TASK_NAMES if tasks is None else [check_task_name(task) for task in tasks]
        return {name for name in names if TASK_SPECS[name](start_info, end_info)}
