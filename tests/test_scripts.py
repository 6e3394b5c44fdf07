"""The end-to-end commands' shared training stage (scripts/train_stage.sh), run by bash with a stand-in for
lerobot-train on PATH: what it is called with, where its log goes, and how a stage resumes or is skipped."""

import os
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# Records its arguments, one per line, then behaves as asked by the environment: FAKE_FAIL=1 exits 1;
# otherwise it writes the checkpoint a real run leaves (so a second call can resume from it).
FAKE_TRAIN = """#!/usr/bin/env bash
printf '%s\\n' "$@" > "$FAKE_CALLS/call_$(ls "$FAKE_CALLS" | wc -l)"
echo "training output"
[ "${FAKE_FAIL:-0}" = 1 ] && exit 1
for arg in "$@"; do
    case "$arg" in --output_dir=*) out="${arg#--output_dir=}" ;; esac
done
if [ -n "${out:-}" ]; then
    mkdir -p "$out/checkpoints/last/pretrained_model"
    echo '{}' > "$out/checkpoints/last/pretrained_model/train_config.json"
fi
"""

pytestmark = pytest.mark.skipif(shutil.which("bash") is None, reason="bash is not installed")


@pytest.fixture
def fake_env(tmp_path):
    bin_dir, calls = tmp_path / "bin", tmp_path / "calls"
    bin_dir.mkdir()
    calls.mkdir()
    fake = bin_dir / "lerobot-train"
    fake.write_text(FAKE_TRAIN)
    fake.chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}", "FAKE_CALLS": str(calls)}
    return env, calls


def run_stage(env, out: Path, log: Path, *flags: str) -> subprocess.CompletedProcess:
    script = f'set -euo pipefail; source "{REPO}/scripts/train_stage.sh"; resumable_train "$@"'
    return subprocess.run(
        ["bash", "-c", script, "stage", str(out), str(log), *flags],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )


def calls_made(calls: Path) -> list[list[str]]:
    return [p.read_text().split("\n")[:-1] for p in sorted(calls.iterdir())]


def test_a_fresh_stage_logs_into_a_folder_that_does_not_exist_yet(fake_env, tmp_path):
    env, calls = fake_env
    out, log = tmp_path / "run" / "policy" / "train", tmp_path / "run" / "policy" / "train.log"
    result = run_stage(env, out, log, "--steps=10")
    assert result.returncode == 0, result.stderr
    assert calls_made(calls) == [["--steps=10", f"--output_dir={out}"]]
    assert "training output" in log.read_text()
    assert (out / ".done").exists()


def test_a_finished_stage_is_skipped(fake_env, tmp_path):
    env, calls = fake_env
    out, log = tmp_path / "train", tmp_path / "train.log"
    assert run_stage(env, out, log, "--steps=10").returncode == 0
    assert run_stage(env, out, log, "--steps=10").returncode == 0
    assert len(calls_made(calls)) == 1


def test_an_interrupted_stage_resumes_from_its_last_checkpoint(fake_env, tmp_path):
    env, calls = fake_env
    out, log = tmp_path / "train", tmp_path / "train.log"
    assert run_stage(env, out, log, "--steps=10").returncode == 0
    (out / ".done").unlink()  # as if the run had stopped after its last checkpoint
    assert run_stage(env, out, log, "--steps=10").returncode == 0
    config = out / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    assert calls_made(calls)[1] == [f"--config_path={config}", "--resume=true"]
    assert log.read_text().count("training output") == 2  # the resumed run appends to the log


def test_a_failed_training_run_fails_the_stage_and_is_not_marked_done(fake_env, tmp_path):
    env, _ = fake_env
    out, log = tmp_path / "train", tmp_path / "train.log"
    result = run_stage({**env, "FAKE_FAIL": "1"}, out, log, "--steps=10")
    assert result.returncode != 0
    assert not (out / ".done").exists()
