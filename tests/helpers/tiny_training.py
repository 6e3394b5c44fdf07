"""``lerobot-train`` of a tiny SubgoalVLA for a few steps, as a user runs it (the console script)."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

BIN = Path(sys.executable).parent


def run_tiny_training(
    dataset_root: Path, repo_id: str, output_dir: Path, steps: int = 2, extra_flags: Sequence[str] = ()
) -> subprocess.CompletedProcess:
    """``lerobot-train`` for ``steps`` steps of batch 2 on the dataset (``extra_flags`` last: they win)."""
    flags = [
        "--policy.type=subgoalvla", "--policy.preset=tiny", "--policy.device=cpu",
        "--policy.push_to_hub=false", f"--dataset.repo_id={repo_id}", f"--dataset.root={dataset_root}",
        "--dataset.video_backend=pyav", f"--output_dir={output_dir}", f"--steps={steps}", "--batch_size=2",
        "--num_workers=0", f"--save_freq={steps}", "--wandb.enable=false", *extra_flags,
    ]  # fmt: skip
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
    return subprocess.run(
        [str(BIN / "lerobot-train"), *flags], capture_output=True, text=True, env=env, timeout=400
    )


def train_tiny(dataset_root: Path, repo_id: str, output_dir: Path, steps: int = 2) -> Path:
    """Train ``steps`` steps of batch 2 on the dataset; returns the last checkpoint's ``pretrained_model``."""
    result = run_tiny_training(dataset_root, repo_id, output_dir, steps)
    assert result.returncode == 0, (result.stdout + result.stderr)[-3000:]
    return output_dir / "checkpoints" / "last" / "pretrained_model"
