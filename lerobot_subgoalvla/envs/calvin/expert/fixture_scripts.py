"""Task scripts of the scripted CALVIN expert for the desk's fixtures: drawer, sliding door, button, switch.

Split from ``expert_tasks`` (the block scripts) by concern. Handles and the switch knob are measured by ray
casts on the loaded table, so the same code serves the procedural desk and CALVIN's tables A-D (spec 3.2).
"""

from __future__ import annotations

import numpy as np

from lerobot_subgoalvla.envs.calvin.expert.block_scripts import HOME_YAW
from lerobot_subgoalvla.envs.calvin.expert.skills import (
    GRIPPER_CLOSE,
    ExpertFailureError,
    Skill,
    SkillContext,
    down_euler,
    ray_hits,
    tilted_euler,
)

#: Unit vector of the switch lever's travel (spec 3.2: 0.088 m of joint = +0.044 y, +0.076 z).
SWITCH_AXIS = np.array([0.0, 0.5, np.sqrt(3) / 2])
#: Outward normal of the slanted face the switch slides on (toward the robot and up).
SWITCH_NORMAL = np.array([0.0, -np.sqrt(3) / 2, 0.5])


def handle_geometry(ctx: SkillContext, link: str, resolution: float = 0.01) -> dict[str, float]:
    """Measure a door/drawer handle by casting rays toward +y over the link's bounding box.

    The handle is the part of the link that sticks out toward the robot (-y) by more than 1.5 cm from the
    link's face at the same height. Returns its x/z extent, its front y and the face y behind it.
    """
    lo, hi = ctx.link_aabb(link)
    xs = np.arange(lo[0] + 0.005, hi[0] - 0.004, resolution)
    zs = np.arange(lo[2] + 0.005, hi[2] - 0.004, resolution / 2)
    grid = np.array([[x, z] for z in zs for x in xs])
    starts = np.stack([grid[:, 0], np.full(len(grid), lo[1] - 0.3), grid[:, 1]], axis=1)
    ends = np.stack([grid[:, 0], np.full(len(grid), hi[1] + 0.05), grid[:, 1]], axis=1)
    front = ray_hits(ctx, starts, ends, link)[:, 1].reshape(len(zs), len(xs))  # (Z, X) hit y
    valid = np.isfinite(front).sum(axis=1) >= 3
    front, zs = front[valid], zs[valid]
    face = np.nanpercentile(front, 90, axis=1)  # (Z,) face y per height (the handle covers < 90 %)
    mask = front < face[:, None] - 0.015
    if not mask.any():
        raise ExpertFailureError(f"no handle found on table link {link!r}")
    rows, cols = np.nonzero(mask)
    z_mid = 0.5 * (zs[rows].min() + zs[rows].max())
    slope = np.polyfit(zs, face, 1)[0]  # dy/dz of the face: 0 for the drawer, tan(30 deg) for the door
    return {
        "x_min": float(xs[cols].min()),
        "x_max": float(xs[cols].max()),
        "z_min": float(zs[rows].min()),
        "z_max": float(zs[rows].max()),
        "front_y": float(np.nanmin(front[mask])),
        "face_y": float(np.interp(z_mid, zs, face)),
        "face_slope": float(slope),
    }


def drawer(ctx: SkillContext, opening: bool) -> Skill:
    """Hook the closed fingers behind the drawer handle and pull (open) or push the handle back (close)."""
    handle = handle_geometry(ctx, "drawer_link")
    ctx.gripper = GRIPPER_CLOSE
    # Fingers close along x (thin along y) and lean 40-50 deg toward +y so that
    # the hand stays off the desk edge.
    euler = tilted_euler(HOME_YAW + ctx.rng.uniform(-0.08, 0.08), ctx.rng.uniform(0.7, 0.85))
    x = 0.5 * (handle["x_min"] + handle["x_max"]) + ctx.rng.uniform(-0.02, 0.02)
    z = 0.5 * (handle["z_min"] + handle["z_max"]) + ctx.rng.uniform(-0.004, 0.004)
    behind = handle["face_y"] - 0.022 if opening else handle["front_y"] - 0.025
    yield from ctx.servo(np.array([x, behind - 0.06, z + 0.08]), euler, tol=0.01, what="above handle")
    yield from ctx.servo(
        np.array([x, behind, z]), euler, speed=ctx.motion.slow_speed, tol=0.008, what="handle"
    )
    state = ctx.joint_state("drawer_link")
    travel = ctx.rng.uniform(0.16, 0.19) if opening else -(state + 0.03)
    goal = np.array([x, behind - travel, z])
    yield from ctx.servo(
        goal, euler, speed=ctx.motion.slow_speed, tol=0.01, max_steps=70, what="drawer", allow_timeout=True
    )
    tcp, _ = ctx.tcp()
    back = -0.03 if opening else -0.04
    yield from ctx.servo(tcp + [0, back, 0.0], euler, tol=0.015, what="release handle", allow_timeout=True)
    yield from ctx.servo(ctx.tcp()[0] + [0, 0, 0.1], euler, tol=0.02, what="retreat", allow_timeout=True)


def slider(ctx: SkillContext, direction: float) -> Skill:
    """Push the sliding door's handle sideways (direction -1 = left, +1 = right) with the closed fingers.

    The fingers point into the slanted door (perpendicular to its face) and close along the slope, so the hand
    is thin along x (it passes beside the handle) and stays in front of the door.
    """
    handle = handle_geometry(ctx, "slide_link")
    ctx.gripper = GRIPPER_CLOSE
    face_angle = float(np.arctan(handle["face_slope"]))  # 0 for a vertical face, 30 deg for CALVIN's door
    normal = np.array([0.0, -np.cos(face_angle), np.sin(face_angle)])  # outward, toward the robot
    # Pushing right, the TCP works near the robot base, where a wrist tilted 60
    # deg is hard to reach: lean less.
    lean = 0.0 if direction < 0 else 0.35
    euler = tilted_euler(
        ctx.rng.uniform(-0.08, 0.08), np.pi / 2 - face_angle - lean + ctx.rng.uniform(-0.1, 0.05)
    )
    z = 0.5 * (handle["z_min"] + handle["z_max"]) + ctx.rng.uniform(-0.02, 0.0)
    face_y = handle["face_y"] + handle["face_slope"] * (z - 0.5 * (handle["z_min"] + handle["z_max"]))
    depth = (handle["face_y"] - handle["front_y"]) * np.cos(face_angle)  # handle protrusion along the normal
    side_x = handle["x_max"] + 0.055 if direction < 0 else handle["x_min"] - 0.055  # hand clear of the handle
    contact = np.array([side_x, face_y, z]) + normal * depth * ctx.rng.uniform(0.45, 0.6)
    yield from ctx.servo(
        contact + normal * 0.07, euler, tol=0.012, rot_tol=0.08, max_steps=100, what="before handle"
    )
    yield from ctx.servo(contact, euler, speed=ctx.motion.slow_speed, tol=0.008, what="handle side")
    travel = ctx.rng.uniform(0.22, 0.25)  # includes the ~5 cm gap to the handle
    yield from ctx.servo(
        contact + [direction * travel, 0, 0],
        euler,
        speed=ctx.motion.slow_speed,
        tol=0.01,
        max_steps=70,
        what="slide",
        allow_timeout=True,
    )
    tcp, _ = ctx.tcp()
    yield from ctx.servo(
        tcp + normal * 0.07 + [-direction * 0.01, 0, 0], euler, tol=0.015, what="retreat", allow_timeout=True
    )


def press_button(ctx: SkillContext) -> Skill:
    """Press the button down past its threshold with the closed fingers and let it spring back (LED
    toggles)."""
    lo, hi = ctx.link_aabb("button_link")
    centre = 0.5 * (lo + hi) + np.append(ctx.jitter(0.008, 2), 0.0)
    ctx.gripper = GRIPPER_CLOSE
    euler = down_euler(HOME_YAW + ctx.rng.uniform(-0.2, 0.2))
    top = hi[2]
    yield from ctx.servo(np.array([centre[0], centre[1], top + 0.06]), euler, tol=0.01, what="above button")
    yield from ctx.servo(
        np.array([centre[0], centre[1], top - 0.02]),
        euler,
        speed=ctx.motion.slow_speed,
        tol=0.006,
        max_steps=30,
        what="press",
        allow_timeout=True,
    )
    yield from ctx.hold(GRIPPER_CLOSE, 2)
    yield from ctx.servo(
        np.array([centre[0], centre[1], top + 0.07]),
        euler,
        tol=0.015,
        what="release button",
        allow_timeout=True,
    )


def switch_knob(ctx: SkillContext) -> dict[str, float]:
    """Measure the switch knob in rail coordinates (u along the rail, n out of the slanted face) by rays.

    Rays are cast into the face (-n) over a grid around the switch link; the knob is the outermost part.
    Returns the knob's x centre, its extent along u and its top along n (all relative to the world origin).
    """
    lo, hi = ctx.link_aabb("switch_link")
    centre = 0.5 * (lo + hi)
    grid = np.array([(a, b) for a in np.arange(-0.07, 0.071, 0.01) for b in np.arange(-0.08, 0.081, 0.004)])
    starts = centre + grid[:, :1] * [1, 0, 0] + grid[:, 1:] * SWITCH_AXIS + 0.15 * SWITCH_NORMAL
    hits = ray_hits(ctx, starts, starts - 0.3 * SWITCH_NORMAL, "switch_link")
    hits = hits[np.isfinite(hits[:, 0])]
    if len(hits) == 0:
        raise ExpertFailureError("switch knob not found by ray casts")
    n, u = hits @ SWITCH_NORMAL, hits @ SWITCH_AXIS
    knob = hits[n > n.max() - 0.012]
    return {
        "x": float(np.median(knob[:, 0])),
        "u_min": float((knob @ SWITCH_AXIS).min()),
        "u_max": float((knob @ SWITCH_AXIS).max()),
        "n_top": float(n.max()),
        "u_all_min": float(u.min()),
    }


def move_switch(ctx: SkillContext, up: bool) -> Skill:
    """Slide the switch knob along its rail with the fingertips, pointing into the slanted face.

    Up (lightbulb on): contact on the knob's lower side, push along +u; down: upper side, push along -u.
    """
    knob = switch_knob(ctx)
    ctx.gripper = GRIPPER_CLOSE
    face_angle = np.pi / 6  # the rail climbs at 60 deg: the face normal is 30 deg above horizontal
    # Fingers close along x, so that the hand is thin along the rail and stays above the desk.
    euler = tilted_euler(
        HOME_YAW + ctx.rng.uniform(-0.08, 0.08), np.pi / 2 - face_angle + ctx.rng.uniform(-0.1, 0.05)
    )
    x = knob["x"] + ctx.rng.uniform(-0.025, 0.025)
    u = knob["u_min"] - 0.022 if up else knob["u_max"] + 0.022
    n = knob["n_top"] - ctx.rng.uniform(0.008, 0.014)
    contact = np.array([x, 0.0, 0.0]) + u * SWITCH_AXIS + n * SWITCH_NORMAL
    state = ctx.joint_state("switch_link")
    travel = (0.088 - state if up else state) + ctx.rng.uniform(0.015, 0.025)
    direction = SWITCH_AXIS if up else -SWITCH_AXIS
    yield from ctx.servo(
        contact + 0.06 * SWITCH_NORMAL, euler, tol=0.012, rot_tol=0.08, max_steps=100, what="before switch"
    )
    yield from ctx.servo(contact, euler, speed=ctx.motion.slow_speed, tol=0.007, what="switch start")
    yield from ctx.servo(
        contact + travel * direction,
        euler,
        speed=ctx.motion.slow_speed,
        tol=0.008,
        max_steps=50,
        what="switch",
        allow_timeout=True,
    )
    tcp, _ = ctx.tcp()
    yield from ctx.servo(tcp + 0.07 * SWITCH_NORMAL, euler, tol=0.015, what="retreat", allow_timeout=True)
