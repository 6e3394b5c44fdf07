"""Simulator throughput: control steps per second with both cameras, rendering share, LH-MTLC wall-time
estimate.

Measures, side by side in one run and on ONE core (``--core``, via ``os.sched_setaffinity``):

* ``physics``: ``CalvinSimulation.step`` (IK + 8 x stepSimulation at 240 Hz + button/switch logic);
* ``static`` / ``gripper``: the two images of ``render_cameras()`` (200 x 200 and 84 x 84, TinyRenderer, CPU);
* ``total`` = physics + render per 30 Hz control step, as an evaluation rollout needs it.

Times are CPU time of the calling thread (``time.thread_time``; pybullet DIRECT runs in-process), i.e. what a
step costs on a dedicated core, so that a loaded shared machine still gives meaningful numbers; the load
average is printed for context.

From the total it estimates the simulator-only wall time of the 1000-chain LH-MTLC evaluation (docs/calvin.md
4.3): upper bound 1000 x 5 x 360 steps (every subtask times out), and a typical case in which each chain
completes ``--typical-length`` subtasks of ``--typical-subtask-steps`` steps and then fails one at 360 steps.
Policy inference is added with ``--policy-ms-per-chunk`` (e.g. the "chunk CPU" column of
``policy_benchmark.py``).

``--breakdown`` adds where the static camera's time goes: its CPU ms with each body of the scene removed (the
difference is that body's share) and at other image sizes (TinyRenderer's cost follows the shaded pixels, not
the triangles: the 2-triangle floor plane costs about as much as the table).

Usage:
    python benchmarks/env_benchmark.py                          # procedural (+ calvin_D if assets are found)
    python benchmarks/env_benchmark.py --breakdown --renderers tiny
    python benchmarks/env_benchmark.py --steps 200 --workers 1 4 16 --assets-dir ~/calvin_env
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np
import pybullet

from lerobot_subgoalvla.envs.calvin.evaluation.chain_scene import EVAL_ROBOT_OBS
from lerobot_subgoalvla.envs.calvin.sim.simulation import CalvinSimulation

CHAINS, SUBTASKS, MAX_STEPS = 1000, 5, 360


def _scene_obs() -> np.ndarray:
    obs = np.zeros(24)
    obs[6:24] = [0.05, -0.12, 0.46, 0, 0, 1.3, 0.07, 0.092, 0.461, 0, 0, 1.6, 0.23, -0.12, 0.46, 0, 0, 1.9]
    return obs


def measure(scene: str, assets_dir: Path | None, steps: int, renderer: str = "tiny") -> dict[str, float]:
    """Median CPU ms per control step for physics and rendering, over ``steps`` steps of a smooth random
    walk."""
    rng = np.random.default_rng(0)
    with CalvinSimulation(scene, assets_dir=assets_dir, renderer=renderer) as sim:
        sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=_scene_obs())
        physics, static, gripper = [], [], []
        action = np.zeros(7)
        for t in range(steps):
            action[:6] = np.clip(0.8 * action[:6] + 0.3 * rng.standard_normal(6), -1, 1)
            action[6] = 1.0 if (t // 40) % 2 == 0 else -1.0
            t0 = time.thread_time()
            sim.step(action)
            t1 = time.thread_time()
            sim.cameras.render_static()
            t2 = time.thread_time()
            sim.cameras.render_gripper(*sim.robot.camera_pose())  # what render_cameras() does, timed apart
            t3 = time.thread_time()
            physics.append(t1 - t0)
            static.append(t2 - t1)
            gripper.append(t3 - t2)
    phys_ms, static_ms, gripper_ms = (1000 * statistics.median(x) for x in (physics, static, gripper))
    render_ms = static_ms + gripper_ms
    total_ms = phys_ms + render_ms
    return {
        "physics_ms": phys_ms,
        "static_ms": static_ms,
        "gripper_ms": gripper_ms,
        "render_ms": render_ms,
        "total_ms": total_ms,
        "steps_per_s": 1000 / total_ms,
        "physics_only_steps_per_s": 1000 / phys_ms,
        "render_share": render_ms / total_ms,
    }


def _static_ms(sim: CalvinSimulation, renders: int, size: int | None = None) -> float:
    if size is not None:
        sim.cameras.static_size = size
    times = []
    for _ in range(renders):
        start = time.thread_time()
        sim.cameras.render_static()
        times.append(time.thread_time() - start)
    return 1000 * statistics.median(times)


def static_breakdown(scene: str, assets_dir: Path | None, renders: int = 15) -> list[tuple[str, float]]:
    """(what, static-camera CPU ms) rows: the full scene, the scene without each body (a fresh simulation
    each), no body at all, and the full scene at other image sizes."""
    rows = []
    with CalvinSimulation(scene, assets_dir=assets_dir) as sim:
        sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=_scene_obs())
        rows.append(("full scene, 200 px", _static_ms(sim, renders)))
        bodies = range(sim.client.getNumBodies())
        names = [sim.client.getBodyInfo(uid)[1].decode() or f"body {uid}" for uid in bodies]
    for uid, name in enumerate(names):
        with CalvinSimulation(scene, assets_dir=assets_dir) as sim:
            sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=_scene_obs())
            sim.client.removeBody(uid)
            rows.append((f"without {name}", _static_ms(sim, renders)))
    with CalvinSimulation(scene, assets_dir=assets_dir) as sim:
        sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=_scene_obs())
        for size in (84, 128):
            rows.append((f"full scene, {size} px", _static_ms(sim, renders, size)))
        for uid in range(len(names)):
            sim.client.removeBody(uid)
        rows.append(("no body (background only), 128 px", _static_ms(sim, renders)))
    return rows


def lh_mtlc_hours(
    steps_per_s: float, workers: int, typical_length: float, typical_subtask_steps: int
) -> tuple:
    """(upper bound, typical) hours of the 1000-chain evaluation on ``workers`` single-core workers at
    ``steps_per_s`` control steps per second per worker."""
    upper_steps = CHAINS * SUBTASKS * MAX_STEPS
    per_chain = typical_length * typical_subtask_steps + (MAX_STEPS if typical_length < SUBTASKS else 0)
    typical_steps = CHAINS * per_chain
    rate = steps_per_s * workers
    return upper_steps / rate / 3600, typical_steps / rate / 3600


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--steps", type=int, default=120, help="control steps measured per scene")
    parser.add_argument("--core", type=int, default=0, help="CPU core to pin to (-1: no pinning)")
    parser.add_argument(
        "--workers", type=int, nargs="+", default=[1, 4, 16], help="worker counts for the estimate"
    )
    parser.add_argument(
        "--assets-dir", type=Path, default=None, help="calvin_env clone (default: $CALVIN_ENV_ASSETS)"
    )
    parser.add_argument(
        "--typical-length", type=float, default=3.0, help="completed subtasks per chain (typical)"
    )
    parser.add_argument("--typical-subtask-steps", type=int, default=90, help="steps of a completed subtask")
    parser.add_argument(
        "--policy-ms-per-chunk",
        type=float,
        default=0.0,
        help="policy CPU ms per action chunk for the estimate (policy_benchmark.py's 'chunk CPU'; 0: none)",
    )
    parser.add_argument(
        "--actions-per-chunk",
        type=int,
        default=8,
        help="actions executed per chunk (the policy's n_action_steps)",
    )
    parser.add_argument(
        "--renderers", nargs="+", default=["tiny", "egl"], choices=["tiny", "egl"], help="camera renderers"
    )
    parser.add_argument(
        "--breakdown", action="store_true", help="also break the static camera's time down by body and size"
    )
    args = parser.parse_args()
    # llvmpipe (Mesa's EGL on a CPU) renders in its own threads unless told not to: thread CPU time would
    # miss them
    os.environ.setdefault("LP_NUM_THREADS", "0")
    if args.core >= 0:
        os.sched_setaffinity(0, {args.core})
    assets = args.assets_dir or os.environ.get("CALVIN_ENV_ASSETS")
    default_assets = Path(__file__).resolve().parents[2] / "shared" / "calvin_env_assets"
    if assets is None and (default_assets / "data").is_dir():
        assets = default_assets
    scenes = ["procedural"] + (["calvin_D"] if assets is not None else [])

    print(
        f"pybullet numpy support: {bool(pybullet.isNumpyEnabled())}; pinned core: {args.core}; steps: "
        f"{args.steps}"
    )
    print(f"load average: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores (timings scale with contention)")
    header = (
        f"{'scene':<11} {'renderer':<8} {'physics ms':>10} {'static ms':>9} {'gripper ms':>10} "
        f"{'total ms':>9} "
        f"{'steps/s':>8} "
        f"{'phys-only/s':>11} {'render %':>8}"
    )
    print(header)
    print("-" * len(header))
    results = {}
    for scene, renderer in ((s, r) for s in scenes for r in args.renderers):
        r = measure(scene, Path(assets) if assets else None, args.steps, renderer)
        if renderer == args.renderers[0]:
            results[scene] = r
        print(
            f"{scene:<11} {renderer:<8} {r['physics_ms']:>10.2f} {r['static_ms']:>9.2f} "
            f"{r['gripper_ms']:>10.2f} "
            f"{r['total_ms']:>9.2f} "
            f"{r['steps_per_s']:>8.1f} {r['physics_only_steps_per_s']:>11.1f} "
            f"{100 * r['render_share']:>7.0f}%"
        )
    print("reference   calvin_env scene D, TinyRenderer, one core of the same machine class: 13.9 steps/s")
    if args.breakdown:
        print()
        print("static camera (TinyRenderer), CPU ms per image:")
        for scene in scenes:
            for what, ms in static_breakdown(scene, Path(assets) if assets else None):
                print(f"{scene:<11} {what:<36} {ms:>7.2f}")
    print()
    policy_ms_per_step = args.policy_ms_per_chunk / args.actions_per_chunk
    inference = (
        f"policy {args.policy_ms_per_chunk:g} ms per chunk of {args.actions_per_chunk}"
        if args.policy_ms_per_chunk
        else "simulator only"
    )
    print(
        "LH-MTLC wall time (1000 chains; upper bound 5 x 360 steps; typical "
        f"{args.typical_length:g} "
        f"x {args.typical_subtask_steps} steps + one 360-step failure), hours, with cameras, {inference}:"
    )
    print(f"{'scene':<11} {'workers':>7} {'upper h':>8} {'typical h':>9}")
    for scene, r in results.items():
        steps_per_s = 1000 / (r["total_ms"] + policy_ms_per_step)
        for workers in args.workers:
            upper, typical = lh_mtlc_hours(
                steps_per_s, workers, args.typical_length, args.typical_subtask_steps
            )
            print(f"{scene:<11} {workers:>7} {upper:>8.2f} {typical:>9.2f}")


if __name__ == "__main__":
    main()
