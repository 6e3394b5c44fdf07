"""Scene layout measured from the table body: surfaces, cabinet shelf, drawer, obstacles (spec 3.2-3.3).

The expert and the start-state sampler must work in the procedural scene and in CALVIN's scenes A-D, whose
fixtures sit at different x positions (spec 3.2 table). Instead of per-scene constants, everything is read
from the loaded table (link bounding boxes, joint limits, downward rays), once per sim.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lerobot_subgoalvla.envs.calvin.expert.skills import ExpertFailureError, Motion, SkillContext, ray_hits

if TYPE_CHECKING:
    from lerobot_subgoalvla.envs.calvin.sim.simulation import CalvinSimulation

#: Block rest height on the desk (spec 3.4) and CALVIN's "table" sampling band in y (spec 3.3).
TABLE_BLOCK_Z = 0.46
TABLE_Y = (-0.15, -0.03)


@dataclass(frozen=True)
class SceneLayout:
    """Fixed geometry of the loaded table (world metres)."""

    desk_x: tuple[float, float]  # x extent of the desk top
    desk_front_y: float  # the desk edge toward the robot
    desk_top_z: float  # height of the desk surface
    shelf_x: tuple[float, float]  # x extent of the cabinet shelf (plank link)
    shelf_y: float  # y centre of the shelf
    cabinet_front_y: float  # front (-y) edge of the shelf
    slide_max: float  # sliding door joint upper limit
    drawer_max: float  # drawer joint upper limit
    drawer_x: tuple[float, float]  # x extent of the drawer
    button_xy: tuple[float, float, float, float]  # x_lo, x_hi, y_lo, y_hi of the button
    drawer_open_min: float = 0.15  # drawer state from which blocks fit in / can be taken out

    @staticmethod
    def from_sim(sim: CalvinSimulation) -> SceneLayout:
        return SceneLayout.from_context(SkillContext(sim, np.random.default_rng(0), Motion(0.01, 0.005)))

    @staticmethod
    def from_context(ctx: SkillContext) -> SceneLayout:
        client, table = ctx.sim.client, ctx.table_uid
        base = ctx.link_aabb("base_link")
        plank = ctx.link_aabb("plank_link")
        drawer = ctx.link_aabb("drawer_link")
        button = ctx.link_aabb("button_link")
        return SceneLayout(
            desk_x=(float(base[0, 0]), float(base[1, 0])),
            desk_front_y=float(base[0, 1]),
            desk_top_z=_desk_top(ctx, base),
            shelf_x=(float(plank[0, 0]), float(plank[1, 0])),
            shelf_y=float(0.5 * (plank[0, 1] + plank[1, 1])),
            cabinet_front_y=float(plank[0, 1]),
            slide_max=float(client.getJointInfo(table, ctx.links["slide_link"])[9]),
            drawer_max=float(client.getJointInfo(table, ctx.links["drawer_link"])[9]),
            drawer_x=(float(drawer[0, 0]), float(drawer[1, 0])),
            button_xy=(float(button[0, 0]), float(button[1, 0]), float(button[0, 1]), float(button[1, 1])),
        )

    # ------------------------------------------------------------------------------------- cabinet
    def open_shelf_interval(self, ctx: SkillContext) -> tuple[float, float]:
        """The x interval of the shelf not covered by the sliding door (where blocks go in and out)."""
        door = ctx.link_aabb("slide_link")
        left = (self.shelf_x[0], min(self.shelf_x[1], float(door[0, 0])))
        right = (max(self.shelf_x[0], float(door[1, 0])), self.shelf_x[1])
        return left if left[1] - left[0] >= right[1] - right[0] else right

    def shelf_top(self, ctx: SkillContext, x: float, y: float) -> float:
        hit = ray_hits(ctx, np.array([[x, y, 0.6]]), np.array([[x, y, 0.3]]), "plank_link")[0]
        return float(hit[2]) if not np.isnan(hit[2]) else float(ctx.link_aabb("plank_link")[1, 2])

    def cabinet_reach_interval(self, ctx: SkillContext) -> tuple[float, float]:
        """x interval of the open shelf where the gripper fits: the hand is ~0.22 m wide along x, so the
        fingers must stay 0.125 m from the door's edge and 0.08 m from the cabinet's end wall."""
        lo, hi = self.open_shelf_interval(ctx)
        door = ctx.link_aabb("slide_link")
        door_on_right = door[0, 0] >= hi - 0.01
        return (lo + 0.08, hi - 0.125) if door_on_right else (lo + 0.125, hi - 0.08)

    def block_in_open_cabinet(self, ctx: SkillContext, block: str) -> bool:
        """On the shelf, in the half the door leaves open (CALVIN: slider_left with door right, or vice versa)
        and where the gripper fits (:meth:`cabinet_reach_interval`)."""
        on_shelf = (ctx.table_uid, ctx.links["plank_link"]) in ctx.block_contacts(block)
        lo, hi = self.cabinet_reach_interval(ctx)
        x = float(ctx.block_pose(block)[0][0])
        return on_shelf and lo <= x <= hi

    # -------------------------------------------------------------------------------------- drawer
    def block_in_drawer(self, ctx: SkillContext, block: str) -> bool:
        return (ctx.table_uid, ctx.links["drawer_link"]) in ctx.block_contacts(block)

    def drawer_drop_point(self, ctx: SkillContext, edge_margin: float = 0.06) -> tuple[float, float, float]:
        """A point (x, y, floor z) of the open drawer in front of the desk edge (reachable from above).

        Found by downward rays started just under the desk top, below the robot and the block it holds;
        ``edge_margin`` keeps the point that far in front of the desk edge (room for the hand).
        """
        lo, hi = ctx.link_aabb("drawer_link")
        x = float(ctx.rng.uniform(lo[0] + 0.1, hi[0] - 0.1))
        ys = np.arange(lo[1], self.desk_front_y - edge_margin + 0.035, 0.005)
        start_z = np.full_like(ys, self.desk_top_z - 0.005)
        tops = ray_hits(
            ctx,
            np.stack([np.full_like(ys, x), ys, start_z], axis=1),
            np.stack([np.full_like(ys, x), ys, np.zeros_like(ys)], axis=1),
            "drawer_link",
        )[:, 2]
        floor = np.isfinite(tops) & (tops < np.nanmin(tops) + 0.005)
        if floor.sum() < 2:
            raise ExpertFailureError("the drawer floor is not reachable in front of the desk")
        y_floor = ys[floor]
        y_lo, y_hi = y_floor.min() + 0.035, max(y_floor.min() + 0.035, y_floor.max() - 0.035)
        return x, float(ctx.rng.uniform(y_lo, y_hi)), float(np.nanmin(tops))

    def above_drawer(self, ctx: SkillContext, block: str) -> bool:
        """Block x within the drawer (with margin) and room behind it: pushed toward the robot it falls into
        the
        open drawer (push_into_drawer)."""
        x = float(ctx.block_pose(block)[0][0])
        back_y = float(ctx.sim.client.getAABB(ctx.block_uids[block])[1][1])
        # The fingers start ~3 cm behind the block: that point must stay clear of the cabinet front.
        return self.drawer_x[0] + 0.07 <= x <= self.drawer_x[1] - 0.07 and back_y <= -0.055

    # ---------------------------------------------------------------------------------------- desk
    def grasp_clear_of_cabinet(self, ctx: SkillContext, block: str, yaw: float) -> bool:
        """The hand's footprint (0.24 m along the closing axis (sin yaw, -cos yaw), 0.1 m across) over the
        block
        stays in front of the cabinet front (switch knob, door handle), which it would hit when descending."""
        pos, _ = ctx.block_pose(block)
        reach_y = 0.12 * abs(np.cos(yaw)) + 0.05 * abs(np.sin(yaw))
        return float(pos[1]) + reach_y < float(ctx.link_aabb("switch_link")[0, 1])

    def within_reach(self, ctx: SkillContext, block: str, reach: float = 0.78) -> bool:
        """Block within ``reach`` (horizontal) of the robot base: the Panda's top-down grasps fail beyond."""
        base, _ = ctx.sim.client.getBasePositionAndOrientation(ctx.robot_uid)
        return float(np.linalg.norm(ctx.block_pose(block)[0][:2] - np.asarray(base[:2]))) <= reach

    def push_room(self, ctx: SkillContext, block: str, direction: float) -> bool:
        """Room to push ``block`` 0.17 m along ``direction`` x: stays on the desk, misses button and
        blocks."""
        pos, _ = ctx.block_pose(block)
        start_x, end_x = pos[0] - direction * 0.09, pos[0] + direction * 0.2
        base, _ = ctx.sim.client.getBasePositionAndOrientation(ctx.robot_uid)
        if np.hypot(start_x - base[0], pos[1] - base[1]) > 0.8:  # the finger must reach behind the block
            return False
        lo, hi = min(start_x, end_x), max(start_x, end_x)
        if lo < self.desk_x[0] + 0.05 or hi > self.desk_x[1] - 0.05:
            return False
        bx0, bx1, by0, by1 = self.button_xy
        if by0 - 0.04 < pos[1] < by1 + 0.04 and hi > bx0 - 0.01 and lo < bx1 + 0.01:
            return False
        for other in ctx.block_uids:
            if other == block:
                continue
            opos, _ = ctx.block_pose(other)
            if abs(opos[1] - pos[1]) < 0.08 and lo - 0.05 < opos[0] < hi + 0.05:
                return False
        return True


def _desk_top(ctx: SkillContext, base: np.ndarray) -> float:
    """Desk surface height: median of downward rays along a line 5 cm behind the desk's front edge."""
    xs = np.linspace(base[0, 0] + 0.05, base[1, 0] - 0.05, 9)
    y = base[0, 1] + 0.05
    starts = np.stack([xs, np.full_like(xs, y), np.full_like(xs, 1.0)], axis=1)
    tops = ray_hits(ctx, starts, starts * [1, 1, 0], "base_link")[:, 2]
    if not np.isfinite(tops).any():
        raise ValueError("could not find the desk surface of the table (no downward ray hit base_link)")
    return float(np.nanmedian(tops))
