"""The end-to-end commands' shared stages, run by bash with stand-ins for lerobot-train/-eval on PATH:
the training stage (scripts/train_stage.sh: what it is called with, where its log goes, how it resumes or is
skipped) and the sharded chain stage (scripts/chain_stage.sh: disjoint shards, joined, resumed per shard)."""

import shutil
import subprocess
from pathlib import Path

import pytest
from helpers.stand_ins import REPO, calls_made, run_stage_function, stand_ins

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
    return stand_ins(tmp_path, {"lerobot-train": FAKE_TRAIN})


def run_stage(env, out: Path, log: Path, *flags: str) -> subprocess.CompletedProcess:
    return run_stage_function(env, "train_stage.sh", "resumable_train", str(out), str(log), *flags)


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


# lerobot-eval for CALVIN's chains: appends {"chain_id": i} for each chain of [chain_start, chain_stop) not
# yet in --env.results_path (as --env.resume does); FAKE_STOP_AFTER=n stops with exit 1 after n new chains.
FAKE_EVAL = """#!/usr/bin/env bash
printf '%s\\n' "$@" > "$FAKE_CALLS/call_$(date +%s%N)"
for arg in "$@"; do
    case "$arg" in
        --env.chain_start=*) lo="${arg#*=}" ;; --env.chain_stop=*) hi="${arg#*=}" ;;
        --env.results_path=*) results="${arg#*=}" ;;
    esac
done
written=0
for ((i = lo; i < hi; i++)); do
    grep -qx "{\\"chain_id\\": $i}" "$results" 2>/dev/null && continue
    [ -n "${FAKE_STOP_AFTER:-}" ] && [ "$written" -ge "$FAKE_STOP_AFTER" ] && exit 1
    echo "{\\"chain_id\\": $i}" >> "$results"
    written=$((written + 1))
done
"""


@pytest.fixture
def fake_eval(tmp_path):
    return stand_ins(tmp_path, {"lerobot-eval": FAKE_EVAL})


def run_chains(
    env, eval_dir: Path, first: int, count: int, shards: int, *eval_flags: str
) -> subprocess.CompletedProcess:
    args = ["ckpt", str(eval_dir), str(first), str(count), str(shards), *eval_flags]
    return run_stage_function(env, "chain_stage.sh", "sharded_chains", *args)


def chain_ids(path: Path) -> list[int]:
    return [int(line.split(":")[1].strip(" }")) for line in path.read_text().splitlines()]


def chain_ranges(calls: Path) -> list[tuple[str, str]]:
    ranges = []
    for call in sorted(calls.iterdir()):
        flags = dict(arg.split("=", 1) for arg in call.read_text().split() if "=" in arg)
        ranges.append((flags["--env.chain_start"], flags["--env.chain_stop"]))
    return sorted(ranges)


def test_chains_are_split_into_disjoint_shards_and_joined(fake_eval, tmp_path):
    env, calls = fake_eval
    result = run_chains(env, tmp_path / "eval", 100, 100, 2)
    assert result.returncode == 0, result.stderr
    assert chain_ranges(calls) == [("100", "150"), ("150", "200")]
    assert sorted(chain_ids(tmp_path / "eval" / "lh_mtlc" / "results.jsonl")) == list(range(100, 200))
    assert run_chains(env, tmp_path / "eval", 100, 100, 2).returncode == 0  # finished: skipped
    assert len(list(calls.iterdir())) == 2


def test_a_stopped_chain_stage_fails_then_resumes_each_shard_where_it_stopped(fake_eval, tmp_path):
    env, calls = fake_eval
    stopped = run_chains({**env, "FAKE_STOP_AFTER": "7"}, tmp_path / "eval", 0, 30, 3)
    assert stopped.returncode != 0
    assert not (tmp_path / "eval" / "lh_mtlc" / "results.jsonl").exists()
    assert run_chains(env, tmp_path / "eval", 0, 30, 3).returncode == 0
    assert sorted(chain_ids(tmp_path / "eval" / "lh_mtlc" / "results.jsonl")) == list(range(30))
    logs = sorted(p.name for p in (tmp_path / "eval").glob("lh_mtlc_shard*.log"))
    assert logs == [f"lh_mtlc_shard{k}_from_{n}.log" for k in range(3) for n in (0, 7)]


def test_extra_flags_reach_every_shards_lerobot_eval(fake_eval, tmp_path):
    env, calls = fake_eval
    flags = ("--env.static_image_size=84", "--env.gripper_image_size=84")
    assert run_chains(env, tmp_path / "eval", 0, 4, 2, *flags).returncode == 0
    for call in calls.iterdir():
        assert set(flags) <= set(call.read_text().split())


def run_dit_flags(clip: Path) -> subprocess.CompletedProcess:
    script = (
        f'set -euo pipefail; cd "{REPO}"; source scripts/train_stage.sh; '
        'line="$(multi_task_dit_flags "$1")"; read -r -a flags <<< "$line"; printf "%s\\n" "${flags[@]}"'
    )
    command = ["bash", "-c", script, "stage", str(clip)]
    return subprocess.run(command, capture_output=True, text=True, timeout=300)


def test_the_baselines_flags_name_a_random_clip_saved_once(tmp_path):
    result = run_dit_flags(tmp_path / "random_clip")
    assert result.returncode == 0, result.stderr
    flags = result.stdout.split()
    assert "--policy.type=multi_task_dit" in flags
    assert f"--policy.vision_encoder_name={tmp_path / 'random_clip'}" in flags
    assert (tmp_path / "random_clip" / "config.json").is_file()


def test_a_clip_folder_the_baseline_cannot_use_fails_the_caller(tmp_path):
    result = run_dit_flags(tmp_path / "towers")  # multi_task_dit needs "clip" in the name
    assert result.returncode != 0
    assert result.stdout == ""
