"""Meta-World evaluation speed: env steps per second of ``lerobot-eval``'s loop for a trained checkpoint, one
env in the process against LeRobot's async vector env with one worker per core, and where the time goes.

Both modes run LeRobot's own evaluation loop (``lerobot.scripts.lerobot_eval.rollout``) on the same episode
seeds. In the in-process mode (``sync``, 1 env) the Meta-World env's ``render`` and ``step`` and the policy's
``select_action`` are timed from the outside (nothing changes what they compute): the shares say what an
evaluation step costs. In the ``async`` mode (``--envs`` workers, ``use_async_envs``, what the Meta-World
command runs) only the wall time is measured: the env workers render in their own processes, in parallel with
each other and with the policy. An episode that succeeds ends there; one that does not runs LeRobot's 500-step
limit, so steps/s, not episodes/s, compares the modes.

Usage:
    MUJOCO_GL=egl OMP_NUM_THREADS=1 python benchmarks/metaworld_eval_speed.py \\
        --policy-path outputs/metaworld/subgoalvla/train/checkpoints/last/pretrained_model --task reach-v3
"""

from __future__ import annotations

import argparse
import contextlib
import io
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


def _timed(seconds: dict[str, float], name: str, method: Callable) -> Callable:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return method(*args, **kwargs)
        finally:
            seconds[name] += time.perf_counter() - start

    return wrapper


def run_mode(policy_path: Path, task: str, envs: int, episodes: int, first_seed: int) -> dict[str, Any]:
    """``episodes`` episodes of ``task`` in batches of ``envs``; returns steps, wall time and the shares."""
    from lerobot.envs import make_env, make_env_pre_post_processors
    from lerobot.envs.configs import MetaworldEnv
    from lerobot.scripts.lerobot_eval import rollout

    from lerobot_subgoalvla.visualization.checkpoint import load_policy

    policy, pre, post = load_policy(policy_path)
    env_cfg = MetaworldEnv(task=task)
    env_pre, env_post = make_env_pre_post_processors(env_cfg, policy.config)
    with contextlib.redirect_stdout(io.StringIO()):
        vector_env = make_env(env_cfg, n_envs=envs, use_async_envs=envs > 1)[task][0]
    seconds = {"render": 0.0, "physics": 0.0, "policy": 0.0}
    if envs == 1:  # in-process: tap the Meta-World env under LeRobot's wrapper
        inner_env = vector_env.envs[0]
        inner_env._ensure_env()
        inner_env._env.render = _timed(seconds, "render", inner_env._env.render)
        inner_env._env.step = _timed(seconds, "physics", inner_env._env.step)
    policy.select_action = _timed(seconds, "policy", policy.select_action)
    steps, successes, start = 0, 0, time.perf_counter()
    try:
        for batch_start in range(0, episodes, envs):
            seeds = list(range(first_seed + batch_start, first_seed + batch_start + envs))
            data = rollout(vector_env, policy, env_pre, env_post, pre, post, seeds=seeds)
            done = data["done"].numpy()  # (envs, T) cumulative
            steps += int(sum(np.argmax(row) + 1 if row.any() else len(row) for row in done))
            successes += int(data["success"].any(dim=1).sum())
    finally:
        vector_env.close()
    wall = time.perf_counter() - start
    shares = {name: value / wall for name, value in seconds.items()} if envs == 1 else {}
    return {
        "envs": envs,
        "episodes": episodes,
        "successes": successes,
        "steps": steps,
        "wall": wall,
        **shares,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy-path", type=Path, required=True, help="a trained checkpoint folder")
    parser.add_argument("--task", default="reach-v3", help="Meta-World task with the -v3 suffix")
    parser.add_argument("--episodes", type=int, default=4, help="episodes per mode (same seeds)")
    parser.add_argument("--envs", type=int, default=2, help="async env workers of the second mode")
    parser.add_argument("--seed", type=int, default=2000, help="first episode seed")
    args = parser.parse_args()
    rows = [run_mode(args.policy_path, args.task, n, args.episodes, args.seed) for n in (1, args.envs)]
    print(f"{'mode':<8}{'envs':>5}{'ok':>6}{'steps':>7}{'wall s':>8}{'steps/s':>9}"
          f"{'render':>8}{'physics':>8}{'policy':>8}")  # fmt: skip
    for row in rows:
        shares = "".join(
            f"{100 * row[k]:>7.1f}%" if k in row else f"{'-':>8}" for k in ("render", "physics", "policy")
        )
        mode = "sync" if row["envs"] == 1 else "async"
        print(
            f"{mode:<8}{row['envs']:>5}{row['successes']:>3}/{row['episodes']:<2}{row['steps']:>7}"
            f"{row['wall']:>8.1f}{row['steps'] / row['wall']:>9.2f}{shares}"
        )
    rate = [row["steps"] / row["wall"] for row in rows]
    print(f"async / sync steps per second: {rate[1] / rate[0]:.2f}x")


if __name__ == "__main__":
    main()
