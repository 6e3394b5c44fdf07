"""Tests of the end-to-end commands' stages (``scripts/*.sh``) without training or simulating anything: the
commands a stage calls (lerobot-train, lerobot-eval, the generator) are replaced on PATH by small bash
stand-ins that record their arguments, and one stage function is run from its sourced file.

A stand-in records each call as ``$FAKE_CALLS/call_<n>``, one argument per line, with the line
``printf '%s\\n' "$(basename "$0")" "$@" > "$FAKE_CALLS/call_$(ls "$FAKE_CALLS" | wc -l)"`` (or without the
name: then the call holds the arguments alone).
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def stand_ins(tmp_path: Path, scripts: dict[str, str]) -> tuple[dict[str, str], Path]:
    """Each name of ``scripts`` on PATH as its bash script; returns the environment to run with (its
    ``FAKE_CALLS`` names the folder the stand-ins record their calls in) and that folder."""
    bin_dir, calls = tmp_path / "bin", tmp_path / "calls"
    bin_dir.mkdir()
    calls.mkdir()
    for name, script in scripts.items():
        (bin_dir / name).write_text(script)
        (bin_dir / name).chmod(0o755)
    return {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}", "FAKE_CALLS": str(calls)}, calls


def run_stage_function(
    env: dict[str, str], script: str, function: str, *args: str, cwd: Path | None = None
) -> subprocess.CompletedProcess:
    """``function "$@"`` from ``scripts/<script>`` (sourced under ``set -euo pipefail``), output captured."""
    line = f'set -euo pipefail; source "{REPO / "scripts" / script}"; {function} "$@"'
    return subprocess.run(
        ["bash", "-c", line, "stage", *args], env=env, cwd=cwd, capture_output=True, text=True, timeout=60
    )


def calls_made(calls: Path) -> list[list[str]]:
    """The recorded calls in the order they were made, each as its list of lines."""
    return [p.read_text().split("\n")[:-1] for p in sorted(calls.iterdir(), key=lambda p: int(p.stem[5:]))]
