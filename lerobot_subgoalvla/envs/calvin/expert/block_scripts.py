"""Task scripts of the scripted CALVIN expert: one generator per task family (spec 2.2-2.3).

Every script is closed loop: it reads the privileged state (block poses, joint states, handle geometry from
ray casts) when a phase starts and yields relative actions (see ``expert_skills``). Waypoints carry small
random offsets drawn from the run's ``np_random`` so that demonstrations vary.

Geometry conventions (spec 0, 3.2): world z up, the robot at y = -0.46 facing +y; the drawer opens toward -y,
the sliding door moves along x (state 0 = door right), the switch lever slides along (0, sin 30, cos 30).
"""

from __future__ import annotations

import numpy as np

from lerobot_subgoalvla.envs.calvin.expert.skills import (
    GRIPPER_CLOSE,
    GRIPPER_OPEN,
    ExpertFailureError,
    Skill,
    SkillContext,
    down_euler,
    tilted_euler,
    wrap_angle,
)

#: Yaw of the TCP in CALVIN's neutral pose (spec 4.2 robot_obs[5]); grasp yaws are chosen near it.
HOME_YAW = 1.5
#: Yaw range that keeps joint 7 away from its limits (+-2.9 rad) for the down-pointing TCP: measured
#: q7 ~ 2.05 - yaw near the desk, so yaw in (-0.85, 4.95); a 0.15 rad margin on each side.
YAW_RANGE = (-0.7, 4.8)
#: Rotations happen at y <= this (m): far enough from the cabinet front for the hand to turn freely.
SAFE_TURN_Y = -0.09
#: Block half height (spec 3.4: 0.04 m cross-section after the 0.8 scaling).
BLOCK_HALF = 0.02


# --------------------------------------------------------------------------------------------- geometry
def grasp_yaw(rotation: np.ndarray, preferred: float = HOME_YAW, turn: float = 0.0) -> float:
    """TCP yaw that closes the fingers across the block's short side (local y), near ``preferred``.

    The fingers close along the TCP's local y = world (sin yaw, -cos yaw) for a down-pointing TCP, so the yaw
    must equal the block's yaw modulo pi (modulo pi/2 would also do for the cube, but pi keeps one rule).
    ``turn`` is a yaw change applied after grasping (rotate tasks): both ends must stay in ``YAW_RANGE``.
    """
    local_y = rotation[:, 1]
    base = float(np.arctan2(local_y[1], local_y[0]) + np.pi / 2)
    candidates = [base + k * np.pi for k in range(-3, 4)]
    feasible = [
        c for c in candidates if YAW_RANGE[0] <= min(c, c + turn) and max(c, c + turn) <= YAW_RANGE[1]
    ]
    if not feasible:
        raise ExpertFailureError(f"no reachable grasp yaw for block yaw {base:.2f} and turn {turn:.2f}")
    return min(feasible, key=lambda c: abs(c + turn / 2 - preferred))


# ---------------------------------------------------------------------------------------------- blocks
def _grasp_once(ctx: SkillContext, block: str, turn: float, tilt: float) -> Skill:
    """Approach ``block`` along the fingers with the gripper open and close them.

    ``tilt`` > 0 leans the fingers toward +y (into the cabinet): the approach then comes from the front and
    above, keeping the hand outside the cabinet's slanted opening (lift_*_slider).
    """
    pos, rot = ctx.block_pose(block)
    yaw = grasp_yaw(rot, turn=turn) + ctx.rng.uniform(-0.05, 0.05)
    euler = tilted_euler(yaw, tilt) if tilt else down_euler(yaw)
    approach = np.array([0.0, np.sin(tilt), -np.cos(tilt)])  # hand -> fingertips
    ctx.gripper = GRIPPER_OPEN
    hover = pos - approach * ctx.rng.uniform(0.07, 0.11) + ctx.jitter(0.01) * [1, 1, 0]
    move = ctx.transit if tilt else ctx.servo  # into the cabinet: keep clear of its front on the way
    # The hover point is only a via point: near the edge of the reach it may stay 1-2 cm short.
    yield from move(
        hover, euler, tol=0.015, rot_tol=0.08, max_steps=70, what=f"above {block}", allow_timeout=True
    )
    pos, rot = ctx.block_pose(block)
    target = pos + np.array([0, 0, ctx.rng.uniform(0.0, 0.006) + (0.006 if tilt else 0.0)])
    yield from ctx.servo(target - 0.03 * approach, euler, tol=0.01, what=f"pre-grasp {block}")
    yield from ctx.servo(
        target,
        euler,
        speed=ctx.motion.slow_speed,
        tol=0.006,
        max_steps=40,
        what=f"grasp {block}",
        allow_timeout=True,
    )
    yield from ctx.set_gripper(GRIPPER_CLOSE)


def grasp(ctx: SkillContext, block: str, turn: float = 0.0, tilt: float = 0.0, attempts: int = 2) -> Skill:
    """Grasp ``block`` (see :func:`_grasp_once`); on a miss, open, back off and try again from its new
    pose."""
    for attempt in range(attempts):
        yield from _grasp_once(ctx, block, turn, tilt)
        if ctx.gripper_width() > 0.01 and ctx.robot_holds(block):
            return
        if attempt + 1 < attempts:
            yield from ctx.set_gripper(GRIPPER_OPEN)
            tcp, euler = ctx.tcp()
            back = np.array([0.0, -np.sin(tilt), np.cos(tilt)]) * 0.06
            yield from ctx.servo(tcp + back, euler, tol=0.02, what="back off", allow_timeout=True)
    raise ExpertFailureError(
        f"grasp of {block} missed {attempts} times (gripper width {ctx.gripper_width():.3f})"
    )


def lift(ctx: SkillContext, block: str, height: float = 0.1) -> Skill:
    """Grasp and lift ``block`` by ``height`` (lift_*: dz 0.05 / 0.03, spec 2.3)."""
    yield from grasp(ctx, block)
    pos, _ = ctx.block_pose(block)
    tcp, euler = ctx.tcp()
    goal = tcp + np.array([0, 0, height + ctx.rng.uniform(0.0, 0.03)])
    yield from ctx.servo(goal, euler, tol=0.01, what=f"lift {block}")
    if not ctx.robot_holds(block):
        raise ExpertFailureError(f"{block} slipped while lifting")


def lift_out(ctx: SkillContext, block: str, exit_y: float) -> Skill:
    """Grasp a block on the cabinet shelf (tilted fingers), raise it and pull it out toward the robot to
    ``exit_y``."""
    # Left of the desk centre the shelf is close to the robot base, where a steep wrist tilt is hard to reach:
    # there the IK swings the wrist near the block (the TCP wobbles by 2-3 cm and knocks it) and the hand
    # catches the cabinet's slanted end wall. A milder tilt avoids both (procedural scene, left-shelf
    # episodes of lift_*_block_slider: 25/28 succeed at 0.55-0.7 rad against 20/28 at 0.75-0.85).
    steep = ctx.block_pose(block)[0][0] > -0.15
    yield from grasp(ctx, block, tilt=ctx.rng.uniform(0.95, 1.05) if steep else ctx.rng.uniform(0.55, 0.7))
    tcp, euler = ctx.tcp()
    yield from ctx.servo(
        tcp + [0, 0, 0.045], euler, speed=ctx.motion.slow_speed, tol=0.01, what=f"raise {block}"
    )
    tcp, _ = ctx.tcp()
    yield from ctx.servo(
        np.array([tcp[0], min(tcp[1], exit_y), tcp[2] + 0.03]), euler, tol=0.015, what=f"carry {block} out"
    )
    if not ctx.robot_holds(block):
        raise ExpertFailureError(f"{block} slipped while lifting")


def rotate(ctx: SkillContext, block: str, direction: float) -> Skill:
    """Grasp, lift 2-3 cm, turn the yaw by ~90 deg (+ = left / counter-clockwise), set down, release.

    A block close to the cabinet is first carried to ``SAFE_TURN_Y`` (at most ~6 cm: the oracle allows 0.1 m).
    """
    turn = direction * ctx.rng.uniform(np.deg2rad(80), np.deg2rad(100))
    yield from grasp(ctx, block, turn=turn)
    tcp, euler = ctx.tcp()
    # Turn away from the cabinet front (switch, door): the hand is 0.22 m wide along its closing axis.
    raised = tcp + [0, 0, ctx.rng.uniform(0.025, 0.035)]
    raised[1] = min(raised[1], SAFE_TURN_Y + ctx.rng.uniform(-0.01, 0.01))
    yield from ctx.servo(raised, euler, tol=0.01, what="raise")
    tcp, euler = ctx.tcp()
    turned = euler + np.array([0, 0, turn])
    yield from ctx.servo(tcp, turned, rot_tol=0.04, max_steps=90, what="turn", allow_timeout=True)
    yield from ctx.servo(
        tcp - [0, 0, 0.02],
        turned,
        speed=ctx.motion.slow_speed,
        tol=0.006,
        max_steps=30,
        what="set down",
        allow_timeout=True,
    )
    yield from release_and_retreat(ctx)


def release_and_retreat(ctx: SkillContext, up: float = 0.08) -> Skill:
    """Open the gripper and move straight up (place/stack: the block must end free of the robot)."""
    yield from ctx.set_gripper(GRIPPER_OPEN)
    tcp, euler = ctx.tcp()
    yield from ctx.servo(tcp + [0, 0, up], euler, tol=0.015, what="retreat", allow_timeout=True)


def push(ctx: SkillContext, block: str, direction: float) -> Skill:
    """Push ``block`` along world x by ~0.13-0.15 m with closed fingers at its side (push_*: |dx| > 0.1)."""
    pos, rot = ctx.block_pose(block)
    half = 0.5 * (np.abs(rot[0, 0]) * _block_length(ctx, block) + np.abs(rot[0, 1]) * 0.04)
    ctx.gripper = GRIPPER_CLOSE
    # Fingers close along x: the hand is thin along y and stays clear of the cabinet front (switch).
    euler = down_euler(HOME_YAW + ctx.rng.uniform(-0.1, 0.1))
    y = pos[1] + ctx.rng.uniform(-0.006, 0.006)
    start = np.array([pos[0] - direction * (half + 0.035), y, pos[2] + 0.012])  # fingertips clear the desk
    yield from ctx.servo(start + [0, 0, 0.08], euler, tol=0.015, what="above push start")
    yield from ctx.servo(start, euler, speed=ctx.motion.slow_speed, tol=0.008, what="push start")
    distance = ctx.rng.uniform(0.17, 0.19)
    end = start + np.array([direction * distance, 0, 0])
    yield from ctx.servo(
        end, euler, speed=ctx.motion.slow_speed, tol=0.01, max_steps=60, what="push", allow_timeout=True
    )
    tcp, _ = ctx.tcp()
    yield from ctx.servo(
        tcp + np.array([-direction * 0.02, 0, 0.08]), euler, tol=0.02, what="retreat", allow_timeout=True
    )


def push_into_drawer(ctx: SkillContext, block: str) -> Skill:
    """Push a table block toward the robot (-y) over the desk edge so that it drops into the open drawer."""
    pos, _ = ctx.block_pose(block)
    ctx.gripper = GRIPPER_CLOSE
    euler = down_euler(HOME_YAW + ctx.rng.uniform(-0.1, 0.1))  # fingers close along x: thin along y
    lo, hi = np.asarray(ctx.sim.client.getAABB(ctx.block_uids[block]))
    behind = 0.5 * (hi[1] - lo[1]) + ctx.rng.uniform(
        0.028, 0.034
    )  # fingers (~1.7 cm thick) clear of the block
    start = np.array([pos[0] + ctx.rng.uniform(-0.006, 0.006), pos[1] + behind, pos[2] + 0.012])
    yield from ctx.servo(start + [0, 0, 0.09], euler, tol=0.015, what="above push start")
    yield from ctx.servo(start, euler, speed=ctx.motion.slow_speed, tol=0.008, what="push start")
    drawer_lo, _ = ctx.link_aabb("drawer_link")
    edge_y = ctx.link_aabb("base_link")[0][1]
    end = np.array([start[0], edge_y - 0.05, start[2]])
    yield from ctx.servo(
        end, euler, speed=ctx.motion.slow_speed, tol=0.01, max_steps=60, what="push", allow_timeout=True
    )
    tcp, _ = ctx.tcp()
    yield from ctx.servo(tcp + [0, 0.03, 0.1], euler, tol=0.02, what="retreat", allow_timeout=True)


def place_on(
    ctx: SkillContext,
    block: str,
    target_xy: np.ndarray,
    surface_z: float,
    tilt: float = 0.0,
    closing_yaw: float | None = None,
) -> Skill:
    """Carry the held block over ``target_xy``, lower it onto ``surface_z`` (its bottom), release, retreat.

    ``tilt`` > 0 leans the fingers toward +y and approaches along them (from the front and above), which is
    how the hand reaches into the cabinet's slanted opening (place_in_slider); the block turns with the
    fingers. ``closing_yaw`` turns the wrist first so that the fingers close along that direction modulo pi
    (tilted placing uses pi/2: fingers along x, block level sideways, hand parallel to the opening).
    """
    tcp, euler = ctx.tcp()
    block_pos, _ = ctx.block_pose(block)
    approach = np.array([0.0, np.sin(tilt), -np.cos(tilt)])  # hand -> fingertips
    # Lowest point of the held block below its centre once turned by ``tilt`` about the closing axis.
    half_height = BLOCK_HALF * (abs(np.cos(tilt)) + abs(np.sin(tilt)))
    offset = (tcp[2] - block_pos[2]) * np.cos(tilt)  # TCP height above the block centre
    drop = np.array([*target_xy, surface_z + half_height + offset + ctx.rng.uniform(0.008, 0.015)])
    if tilt and closing_yaw is None:
        closing_yaw = np.pi / 2
    if closing_yaw is not None:
        yaw = min((closing_yaw + k * np.pi for k in (-1, 0, 1)), key=lambda y: abs(wrap_angle(y - euler[2])))
        yield from ctx.servo(
            tcp + [0, 0, 0.02], down_euler(yaw), tol=0.015, rot_tol=0.06, max_steps=90, what="turn wrist"
        )
        euler = tilted_euler(yaw, tilt) if tilt else down_euler(yaw)
    if tilt:
        yield from ctx.transit(
            drop - 0.1 * approach, euler, tol=0.015, rot_tol=0.08, max_steps=100, what="front"
        )
    else:
        carry_z = max(tcp[2], drop[2] + 0.05)
        yield from ctx.servo(np.array([*target_xy, carry_z]), euler, tol=0.015, what="above")
    yield from ctx.servo(drop, euler, speed=ctx.motion.slow_speed, tol=0.008, what="place")
    if not ctx.robot_holds(block):
        raise ExpertFailureError(f"{block} slipped while carrying")
    yield from ctx.set_gripper(GRIPPER_OPEN)
    tcp, euler = ctx.tcp()
    retreat = tcp - 0.08 * approach if tilt else tcp + [0, 0, 0.06]
    yield from ctx.servo(retreat, euler, tol=0.015, what="retreat", allow_timeout=True)


def _block_length(ctx: SkillContext, block: str) -> float:
    """Long side of a block (local x) from its collision box (spec 3.4: 0.04 / 0.056 / 0.08 m)."""
    lo, hi = np.asarray(ctx.sim.client.getAABB(ctx.block_uids[block]))
    _, rot = ctx.block_pose(block)
    extent = hi - lo
    # For a flat block, the xy extent is |R| @ (L, 0.04); solve for L along the dominant axis.
    cos, sin = abs(rot[0, 0]), abs(rot[1, 0])
    return float((extent[0] - sin * 0.04) / cos if cos > sin else (extent[1] - cos * 0.04) / sin)
