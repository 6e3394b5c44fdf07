"""Sharded training (FSDP, ``configs/accelerate/fsdp_paper.yaml``) on two CPU processes equals plain DDP.

accelerate runs every CPU launch as DDP, so ``lerobot-train`` cannot be launched sharded without GPUs; the
worker (``helpers/sharded_training.py``) repeats lerobot-train's steps under FSDP1 built from the shipped
YAML through accelerate's plugin, across the stage I -> II switch and with gradient checkpointing on. What
only GPUs can confirm (NCCL, bf16 mixed precision, lerobot-train's own FSDP checkpoint gather) is in
docs/memory.md.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

ROOT = Path(__file__).resolve().parents[2]
WORKER = ROOT / "tests" / "helpers" / "sharded_training.py"
ACCELERATE_CONFIG = ROOT / "configs" / "accelerate" / "fsdp_paper.yaml"


@pytest.mark.slow  # ~35 s: two processes train twice (DDP, then FSDP)
def test_fsdp_full_shard_trains_like_ddp_on_two_cpu_processes(tmp_path: Path) -> None:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    command = [
        str(Path(sys.executable).parent / "torchrun"),
        "--nproc_per_node=2",
        "--standalone",
        str(WORKER),
        str(ACCELERATE_CONFIG),
        str(tmp_path),
    ]
    result = subprocess.run(command, capture_output=True, text=True, env=env, timeout=300, check=False)
    assert result.returncode == 0, (result.stdout + result.stderr)[-4000:]
    report = json.loads((tmp_path / "report.json").read_text())
    # one unit per wrapped block (2 CLIP + 2 kept LLaMA layers, 2 cross-attention, 4 DiT blocks) + the root
    assert report["fsdp_units"] == 11
    assert len(report["fsdp_losses"]) == 4
    torch.testing.assert_close(report["fsdp_losses"], report["ddp_losses"], rtol=1e-5, atol=1e-6)
    ddp, fsdp = load_file(tmp_path / "ddp.safetensors"), load_file(tmp_path / "fsdp.safetensors")
    assert fsdp.keys() == ddp.keys()
    assert int(fsdp["optimizer_steps"]) == 4
    moved = [name for name in ddp if "generator.blocks" in name and ddp[name].dtype.is_floating_point]
    assert moved
    for name, value in ddp.items():
        torch.testing.assert_close(fsdp[name], value, rtol=1e-4, atol=1e-6, msg=name)
