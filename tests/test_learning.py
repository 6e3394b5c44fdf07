"""The learning claim in a form that can fail: expert data -> lerobot-train -> closed-loop success in CALVIN.

Marked slow (15 minutes on 2 CPU cores): it runs the user's commands in subprocesses, as the main command
does, on the two LED tasks (the fixture whose button the arm must find and press; different instructions, same
place): 96 expert attempts, the ``laptop`` preset for 1500 steps of batch 32 through both stages, then
``lerobot-eval`` of 10 episodes per task from seeds the data never used. A policy that has not learned
anything succeeds in 0 of them (the untrained arm drifts away, and the expert's start states are drawn so that
the task is not already done); measured: 20 of 20 (seed 3 data, eval seeds 5000..); the bar of 12 of 20 leaves
room for another machine's numerics.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

TASKS = ("turn_on_led", "turn_off_led")
STEPS, BATCH, EPISODES = 1500, 32, 10
MIN_SUCCESSES = 12  # of 2 x 10 episodes


def _bin(name: str) -> str:
    path = Path(sys.executable).with_name(name)
    return str(path) if path.exists() else shutil.which(name) or name


def _run(args: list[str], log: Path) -> None:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"}
    with log.open("w") as handle:
        code = subprocess.call(args, stdout=handle, stderr=subprocess.STDOUT, env=env)
    assert code == 0, f"{args[0]} failed (exit {code}); last lines:\n" + "\n".join(
        log.read_text().splitlines()[-15:]
    )


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_laptop_preset_learns_the_led_tasks_closed_loop(tmp_path: Path) -> None:
    native, root, train = tmp_path / "native", tmp_path / "dataset", tmp_path / "train"
    _run(
        [
            _bin("subgoalvla-generate-calvin"),
            "--output",
            str(native),
            "--num-tasks",
            "96",
            "--seed",
            "3",
            "--tasks-per-segment",
            "4",
            "--workers",
            "2",
            "--tasks",
            ",".join(TASKS),
        ],
        tmp_path / "generate.log",
    )
    _run(
        [
            _bin("subgoalvla-convert-calvin"),
            str(native),
            "--repo-id",
            "local/led",
            "--root",
            str(root),
            "--workers",
            "2",
        ],
        tmp_path / "convert.log",
    )
    _run(
        [
            _bin("lerobot-train"),
            "--policy.type=subgoalvla",
            "--policy.preset=laptop",
            "--policy.push_to_hub=false",
            f"--policy.stage2_start_step={STEPS * 4 // 5}",
            "--dataset.repo_id=local/led",
            f"--dataset.root={root}",
            "--dataset.video_backend=pyav",
            f"--output_dir={train}",
            f"--steps={STEPS}",
            f"--batch_size={BATCH}",
            "--num_workers=1",
            f"--save_freq={STEPS}",
            "--seed=0",
            "--wandb.enable=false",
        ],
        tmp_path / "train.log",
    )
    checkpoint = train / "checkpoints" / "last" / "pretrained_model"
    successes = {}
    for task in TASKS:
        out = tmp_path / "eval" / task
        _run(
            [
                _bin("lerobot-eval"),
                f"--policy.path={checkpoint}",
                "--env.type=calvin",
                f"--env.task={task}",
                f"--eval.n_episodes={EPISODES}",
                "--eval.batch_size=1",
                "--eval.use_async_envs=false",
                f"--output_dir={out}",
                "--seed=5000",
            ],
            tmp_path / f"eval_{task}.log",
        )
        info = json.loads((out / "eval_info.json").read_text())
        successes[task] = sum(bool(s) for entry in info["per_task"] for s in entry["metrics"]["successes"])
    assert sum(successes.values()) >= MIN_SUCCESSES, f"closed-loop successes per task: {successes}"
