"""Success rate of the scripted CALVIN expert per task, measured by the task oracle (docs/calvin_expert.md).

For each task and episode: a random valid start (``start_states.sample_start_state``, seeded by the episode
index), then the expert acts until the oracle (``TaskOracle.is_completed``) fires or ``--max-steps`` (CALVIN's
subtask budget, 360) pass. Prints task | successes/episodes | rate | mean steps (successful episodes).

    python benchmarks/expert_success.py --scene procedural --episodes 20
    python benchmarks/expert_success.py --scene calvin_D --assets-dir /path/to/calvin_env --workers 2
    python benchmarks/expert_success.py --tasks open_drawer lift_red_block_table --episodes 5
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from lerobot_subgoalvla.calvin_vocab import TASK_NAMES
from lerobot_subgoalvla.envs.calvin.expert.scripted_expert import ScriptedExpert
from lerobot_subgoalvla.envs.calvin.expert.start_states import sample_start_state
from lerobot_subgoalvla.envs.calvin.oracle.tasks import TaskOracle
from lerobot_subgoalvla.envs.calvin.sim.simulation import CalvinSimulation

logger = logging.getLogger("expert_success")


def run_task(task: str, scene: str, assets_dir: str | None, episodes: int, max_steps: int) -> dict:
    """Episodes of one task; returns counts, steps of successes and failure reasons."""
    sim = CalvinSimulation(scene=scene, assets_dir=assets_dir, cameras=False)
    oracle = TaskOracle()
    successes, steps, reasons = 0, [], {}
    try:
        for episode in range(episodes):
            rng = np.random.default_rng([episode, TASK_NAMES.index(task)])
            try:
                sample_start_state(task, sim, rng)
            except RuntimeError as error:
                reasons[str(error)] = reasons.get(str(error), 0) + 1
                continue
            start_info = sim.get_info()
            expert = ScriptedExpert(sim, task, rng)
            for step in range(1, max_steps + 1):
                sim.step(expert.act())
                if oracle.is_completed(task, start_info, sim.get_info()):
                    successes += 1
                    steps.append(step)
                    break
            else:
                reason = expert.failure or ("script ended" if expert.done else "step budget")
                reasons[reason] = reasons.get(reason, 0) + 1
    finally:
        sim.close()
    return {"task": task, "successes": successes, "episodes": episodes, "steps": steps, "reasons": reasons}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="procedural", help="procedural | calvin_A .. calvin_D")
    parser.add_argument("--assets-dir", default=os.environ.get("CALVIN_ENV_ASSETS"), help="calvin_env clone")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--tasks", nargs="*", default=list(TASK_NAMES))
    parser.add_argument("--max-steps", type=int, default=360)
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stdout, force=True)
    if args.scene.startswith("calvin_") and (args.assets_dir is None or not Path(args.assets_dir).is_dir()):
        logger.error(
            "--assets-dir (or $CALVIN_ENV_ASSETS) must point to a calvin_env clone for %s", args.scene
        )
        sys.exit(2)
    unknown = [t for t in args.tasks if t not in TASK_NAMES]
    if unknown:
        logger.error("--tasks: unknown task(s) %s; valid: %s", unknown, ", ".join(TASK_NAMES))
        sys.exit(2)
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        futures = [
            pool.submit(run_task, t, args.scene, args.assets_dir, args.episodes, args.max_steps)
            for t in args.tasks
        ]
        for future in as_completed(futures):
            r = future.result()
            logger.info("done %s: %d/%d %s", r["task"], r["successes"], r["episodes"], r["reasons"] or "")
        results = [f.result() for f in futures]
    logger.info("scene %s, %d episodes per task, budget %d steps", args.scene, args.episodes, args.max_steps)
    logger.info("| task | successes | rate | mean steps |\n|---|---|---|---|")
    for r in results:
        mean = f"{np.mean(r['steps']):.0f}" if r["steps"] else "-"
        logger.info("| %s | %d/%d | %.2f | %s |", r["task"], r["successes"], r["episodes"],
                    r["successes"] / r["episodes"], mean)  # fmt: skip
    total = sum(r["successes"] for r in results) / sum(r["episodes"] for r in results)
    logger.info("overall success rate: %.3f", total)
    for r in results:
        if r["reasons"]:
            logger.info("failures %s: %s", r["task"], r["reasons"])


if __name__ == "__main__":
    main()
