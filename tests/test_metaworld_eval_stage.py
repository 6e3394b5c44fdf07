"""The Meta-World command's evaluation stage (scripts/metaworld_eval.sh), run by bash with a stand-in for
LeRobot's lerobot-eval on PATH: the tasks it evaluates, in which order and from which seed, what it skips, and
that a failed evaluation stops the stage."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.stand_ins import calls_made, run_stage_function, stand_ins

# Records its arguments, one per line, and writes the eval_info.json a real run leaves under --output_dir;
# FAKE_FAIL=<task> makes that task's evaluation exit 1 after writing a partial folder.
FAKE_EVAL = """#!/usr/bin/env bash
printf '%s\\n' "$@" > "$FAKE_CALLS/call_$(ls "$FAKE_CALLS" | wc -l)"
out=""
task=""
for arg in "$@"; do
    case "$arg" in
        --output_dir=*) out="${arg#--output_dir=}" ;;
        --env.task=*) task="${arg#--env.task=}" ;;
    esac
done
mkdir -p "$out/videos"
if [ "${FAKE_FAIL:-}" = "$task" ]; then echo "evaluation of $task broke"; exit 1; fi
echo '{"overall": {"pc_success": 30.0, "n_episodes": 10}}' > "$out/eval_info.json"
"""

pytestmark = pytest.mark.skipif(shutil.which("bash") is None, reason="bash is not installed")


@pytest.fixture
def fake_env(tmp_path):
    env, calls = stand_ins(tmp_path, {"lerobot-eval": FAKE_EVAL})
    # The stage prints each task's success with `python`; the interpreter running the tests is one.
    (tmp_path / "bin" / "python").symlink_to(sys.executable)
    return env, calls


def run_stage(env, eval_dir: Path, tasks: str, *flags: str, **extra_env: str) -> subprocess.CompletedProcess:
    args = ["/ckpt/pretrained_model", str(eval_dir), "2000", "10", tasks, *flags]
    return run_stage_function({**env, **extra_env}, "metaworld_eval.sh", "metaworld_evaluate", *args)


def test_tasks_are_evaluated_in_order_from_the_seed_with_the_extra_flags(fake_env, tmp_path):
    env, calls = fake_env
    result = run_stage(env, tmp_path / "eval", "push-v3,reach-v3", "--policy.n_action_steps=4")
    assert result.returncode == 0, result.stderr
    made = calls_made(calls)
    assert [next(a for a in call if a.startswith("--env.task=")) for call in made] == [
        "--env.task=push-v3",
        "--env.task=reach-v3",
    ]
    for call in made:
        assert {"--seed=2000", "--eval.n_episodes=10", "--env.type=metaworld"} <= set(call)
        assert "--policy.path=/ckpt/pretrained_model" in call
        assert call[-1] == "--policy.n_action_steps=4"  # after the stage's own flags, so it wins
    assert "push-v3: 30 % of 10 episodes" in result.stdout
    written = json.loads((tmp_path / "eval" / "reach-v3" / "eval_info.json").read_text())
    assert written["overall"]["n_episodes"] == 10


def test_an_evaluated_task_is_skipped_and_a_half_written_one_is_evaluated_again(fake_env, tmp_path):
    env, calls = fake_env
    eval_dir = tmp_path / "eval"
    (eval_dir / "push-v3").mkdir(parents=True)
    (eval_dir / "push-v3" / "eval_info.json").write_text('{"kept": true}')
    (eval_dir / "reach-v3" / "videos").mkdir(parents=True)
    (eval_dir / "reach-v3" / "stale.mp4").write_text("cut")
    assert run_stage(env, eval_dir, "push-v3,reach-v3").returncode == 0
    (call,) = calls_made(calls)
    assert "--env.task=reach-v3" in call
    assert json.loads((eval_dir / "push-v3" / "eval_info.json").read_text()) == {"kept": True}
    assert not (eval_dir / "reach-v3" / "stale.mp4").exists()


def test_a_failed_evaluation_stops_the_stage_with_its_log_tail(fake_env, tmp_path):
    env, calls = fake_env
    result = run_stage(env, tmp_path / "eval", "push-v3,reach-v3", FAKE_FAIL="push-v3")
    assert result.returncode == 1
    assert "evaluation of push-v3 broke" in result.stderr
    assert len(calls_made(calls)) == 1  # reach-v3 was not started
    assert not (tmp_path / "eval" / "push-v3" / "eval_info.json").exists()
