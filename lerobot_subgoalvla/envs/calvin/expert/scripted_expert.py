"""Scripted expert for the 34 CALVIN tasks, from privileged simulator state (docs/architecture.md, the
"expert" seam).

``ScriptedExpert(sim, task, np_random)`` picks the script of the task's family (``expert_tasks``,
``expert_fixtures``) and yields one relative action per ``act()`` call; the caller steps the sim, so a data
generator can record every frame. The script reads the state between steps (closed loop), so small physics
deviations are corrected. ``done`` turns True when the script finished; ``failure`` then holds a reason if it
gave up (e.g. a missed grasp).

``is_feasible(task, sim)`` says whether a task applies in the current state (the symbolic preconditions of
CALVIN's chain generator, spec 4.1, plus geometric margins the expert needs, e.g. room to push a block).

Example:
    >>> expert = ScriptedExpert(sim, "open_drawer", np.random.default_rng(0))
    >>> while not expert.done:
    ...     sim.step(expert.act())
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from lerobot_subgoalvla.calvin_vocab import check_task_name
from lerobot_subgoalvla.envs.calvin.expert import block_scripts as scripts
from lerobot_subgoalvla.envs.calvin.expert import fixture_scripts as fixtures
from lerobot_subgoalvla.envs.calvin.expert.layout import SceneLayout
from lerobot_subgoalvla.envs.calvin.expert.skills import (
    GRIPPER_CLOSE,
    GRIPPER_OPEN,
    ExpertFailureError,
    Motion,
    Skill,
    SkillContext,
)

if TYPE_CHECKING:
    from lerobot_subgoalvla.envs.calvin.sim.simulation import CalvinSimulation

logger = logging.getLogger(__name__)


class ScriptedExpert:
    """Closed-loop scripted demonstrator for one CALVIN task.

    Args:
        sim: the simulation to read privileged state from (the caller steps it with ``act()``'s actions).
        task: one of the 34 task names (``calvin_vocab.TASK_NAMES``).
        np_random: randomness of waypoints and speeds (demonstrations vary; same seed = same actions).
    """

    def __init__(self, sim: CalvinSimulation, task: str, np_random: np.random.Generator) -> None:
        self.task = check_task_name(task)
        motion = Motion(
            speed=float(np_random.uniform(0.010, 0.015)), slow_speed=float(np_random.uniform(0.005, 0.007))
        )
        self._ctx = SkillContext(sim, np_random, motion)
        self._script = _lazy_script(self.task, self._ctx)
        self.done = False
        self.failure: str | None = None
        self.steps = 0

    def act(self) -> np.ndarray:
        """Next relative action (7,): pos/0.02, euler/0.05 in [-1, 1], gripper +1 open / -1 close."""
        if not self.done:
            try:
                action = next(self._script)
                self.steps += 1
                return action
            except StopIteration:
                self.done = True
            except ExpertFailureError as failure:
                self.done, self.failure = True, str(failure)
                logger.debug("expert for %s failed: %s", self.task, failure)
        return np.array([0, 0, 0, 0, 0, 0, self._ctx.gripper], dtype=np.float64)


# ------------------------------------------------------------------------------------------- dispatch
def _lazy_script(task: str, ctx: SkillContext) -> Skill:
    """Plan at the first ``act()`` (not in the constructor), so that planning failures end the run cleanly."""
    yield from _script_for(task, ctx, SceneLayout.from_context(ctx))


def _script_for(task: str, ctx: SkillContext, layout: SceneLayout) -> Skill:
    parts = task.split("_")
    if task.startswith("rotate_"):
        return scripts.rotate(ctx, f"block_{parts[1]}", direction=1.0 if parts[-1] == "left" else -1.0)
    if task.startswith("push_into"):
        return scripts.push_into_drawer(ctx, _push_into_candidate(ctx, layout))
    if task.startswith("push_"):
        return scripts.push(ctx, f"block_{parts[1]}", direction=1.0 if parts[-1] == "right" else -1.0)
    if task.startswith("move_slider"):
        return fixtures.slider(ctx, direction=-1.0 if parts[-1] == "left" else 1.0)
    if task in ("open_drawer", "close_drawer"):
        return fixtures.drawer(ctx, opening=task == "open_drawer")
    if task.startswith("lift_"):
        return _lift_script(ctx, layout, f"block_{parts[1]}", parts[-1])
    if task == "place_in_slider":
        return _place_script(ctx, layout, "slider")
    if task == "place_in_drawer":
        return _place_script(ctx, layout, "drawer")
    if task == "stack_block":
        return _place_script(ctx, layout, "stack")
    if task == "unstack_block":
        return scripts.lift(ctx, _stacked_top(ctx), height=0.08)
    if task.startswith("turn_") and task.endswith("led"):
        return fixtures.press_button(ctx)
    return fixtures.move_switch(ctx, up=task == "turn_on_lightbulb")


def _lift_script(ctx: SkillContext, layout: SceneLayout, block: str, surface: str) -> Skill:
    if surface == "slider":
        return scripts.lift_out(ctx, block, exit_y=layout.cabinet_front_y - 0.07)
    return scripts.lift(ctx, block, height=0.1)


def _place_script(ctx: SkillContext, layout: SceneLayout, where: str) -> Skill:
    block = held_block(ctx)
    if block is None:
        raise ExpertFailureError(f"{where}: no block is held")
    if where == "slider":
        lo, hi = layout.open_shelf_interval(ctx)  # the hand (0.22 m wide) fits only about centred
        x = 0.5 * (lo + hi) + ctx.rng.uniform(-0.012, 0.012)
        y = layout.shelf_y + ctx.rng.uniform(-0.01, 0.01)
        surface = layout.shelf_top(ctx, x, y)
        tilt = ctx.rng.uniform(0.95, 1.05) if x > -0.15 else ctx.rng.uniform(0.75, 0.85)  # see lift_out
        return scripts.place_on(ctx, block, np.array([x, y]), surface, tilt=tilt)
    if where == "drawer":
        yaw = ctx.tcp()[1][2]  # the hand is ~0.22 m wide along the closing axis (sin yaw, -cos yaw)
        x, y, floor_z = layout.drawer_drop_point(
            ctx, 0.11 * abs(np.cos(yaw)) + 0.05 * abs(np.sin(yaw)) + 0.01
        )
        return scripts.place_on(ctx, block, np.array([x, y]), floor_z)
    others = [b for b in ctx.block_uids if b != block and _stack_base(ctx, b)]
    if not others:
        raise ExpertFailureError("stack_block: no other block rests on the table")
    tcp, _ = ctx.tcp()
    base = min(others, key=lambda b: float(np.linalg.norm(ctx.block_pose(b)[0][:2] - tcp[:2])))
    base_pos, _ = ctx.block_pose(base)
    # Fingers along y: the held block's long side lies along x, parallel to the cabinet front, so that a block
    # stacked close to the cabinet does not touch the sliding door.
    return scripts.place_on(ctx, block, base_pos[:2] + ctx.jitter(0.004, 2), base_pos[2] + scripts.BLOCK_HALF,
                            closing_yaw=0.0)  # fmt: skip


# --------------------------------------------------------------------------------- symbolic predicates
def held_block(ctx: SkillContext) -> str | None:
    """The block held in the air: touching the robot and nothing else (spec 2.2, place)."""
    for block in ctx.block_uids:
        bodies = {uid for uid, _ in ctx.block_contacts(block)}
        if bodies == {ctx.robot_uid} and ctx.gripper_width() > 0.01:
            return block
    return None


def _on_table(ctx: SkillContext, block: str) -> bool:
    """Resting on the desk (table base link) only, i.e. CALVIN's symbolic ``X = table``."""
    return ctx.block_contacts(block) == {(ctx.table_uid, ctx.links["base_link"])}


#: Stack bases must lie at y <= this (m): closer to the cabinet, the hand placing (and later grasping) the top
#: block touches the sliding door or the switch.
STACK_BASE_MAX_Y = -0.085


def _stack_base(ctx: SkillContext, block: str) -> bool:
    """A table block on which the expert stacks: on the desk and far enough from the cabinet front."""
    return _on_table(ctx, block) and float(ctx.block_pose(block)[0][1]) <= STACK_BASE_MAX_Y


def _stacked_top(ctx: SkillContext) -> str:
    block_uids = set(ctx.block_uids.values())
    for block in ctx.block_uids:
        bodies = {uid for uid, _ in ctx.block_contacts(block)}
        if bodies and bodies <= block_uids:
            return block
    raise ExpertFailureError("unstack_block: no block rests on another block")


def _push_into_candidate(ctx: SkillContext, layout: SceneLayout) -> str:
    candidates = [b for b in ctx.block_uids if _on_table(ctx, b) and layout.above_drawer(ctx, b)]
    if not candidates:
        raise ExpertFailureError("push_into_drawer: no table block in front of the open drawer")
    return min(candidates, key=lambda b: float(ctx.block_pose(b)[0][1]))


def is_feasible(task: str, sim: CalvinSimulation) -> bool:
    """Whether ``task`` applies in the sim's current state (spec 4.1 preconditions + the expert's margins)."""
    check_task_name(task)
    ctx = SkillContext(sim, np.random.default_rng(0), Motion(0.01, 0.005))
    layout = SceneLayout.from_context(ctx)
    held = held_block(ctx)
    parts = task.split("_")
    block = f"block_{parts[1]}" if parts[0] in ("rotate", "push", "lift") and parts[1] != "into" else None
    if task == "place_in_slider":  # spec 4.1: at most one block per cabinet slot
        lo, hi = layout.open_shelf_interval(ctx)
        occupied = any(
            (ctx.table_uid, ctx.links["plank_link"]) in ctx.block_contacts(b)
            and lo - 0.03 < ctx.block_pose(b)[0][0] < hi + 0.03
            for b in ctx.block_uids
        )
        return held is not None and not occupied
    if task == "place_in_drawer":
        return held is not None and ctx.joint_state("drawer_link") > layout.drawer_open_min
    if task == "stack_block":
        return held is not None and any(_stack_base(ctx, b) for b in ctx.block_uids if b != held)
    if held is not None or ctx.gripper_width() < 0.005 and ctx.gripper < 0:
        return False  # every other task starts with empty hands (grasped = 0)
    if task == "unstack_block":
        try:
            _stacked_top(ctx)
        except ExpertFailureError:
            return False
        return True
    if block is not None and task.endswith("_slider"):
        return layout.block_in_open_cabinet(ctx, block)
    if block is not None and task.endswith("_drawer"):
        return ctx.joint_state("drawer_link") > layout.drawer_open_min and layout.block_in_drawer(ctx, block)
    if block is not None:
        on_table = _on_table(ctx, block) and layout.within_reach(ctx, block)
        if parts[0] == "push":
            return on_table and layout.push_room(ctx, block, 1.0 if parts[-1] == "right" else -1.0)
        try:
            yaw = scripts.grasp_yaw(ctx.block_pose(block)[1])
        except ExpertFailureError:
            return False
        return on_table and layout.grasp_clear_of_cabinet(ctx, block, yaw)
    return _fixture_feasible(task, ctx, layout)


def _fixture_feasible(task: str, ctx: SkillContext, layout: SceneLayout) -> bool:
    slide, drawer = ctx.joint_state("slide_link"), ctx.joint_state("drawer_link")
    info = ctx.sim.get_info()["scene_info"]["lights"]
    if task == "move_slider_left":
        return slide < layout.slide_max - 0.17
    if task == "move_slider_right":
        return slide > 0.17
    if task == "open_drawer":
        return drawer < layout.drawer_max - 0.14
    if task == "close_drawer":
        return drawer > 0.14
    if task == "push_into_drawer":
        try:
            _push_into_candidate(ctx, layout)
        except ExpertFailureError:
            return False
        return drawer > layout.drawer_open_min
    light = "lightbulb" if task.endswith("lightbulb") else "led"
    return int(info[light]["logical_state"]) == (0 if task.startswith("turn_on") else 1)


__all__ = ["GRIPPER_CLOSE", "GRIPPER_OPEN", "ScriptedExpert", "held_block", "is_feasible"]
