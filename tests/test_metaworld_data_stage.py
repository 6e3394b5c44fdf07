"""The Meta-World command's data stage (scripts/metaworld_data.sh), run by bash with stand-ins for the
generator and LeRobot's lerobot-edit-dataset on PATH: what each is called with, that more episodes of some
tasks come from another seed and are merged, and that a failed merge leaves no training data behind."""

import shutil
import subprocess
from pathlib import Path

import pytest
from helpers.stand_ins import calls_made, run_stage_function, stand_ins

# Both record their arguments, one per line, and write the finished dataset a real run leaves
# (`meta/info.json` under --output-root / --new_root); FAKE_FAIL=<name> makes that one exit 1 half-way.
FAKE = """#!/usr/bin/env bash
printf '%s\\n' "$(basename "$0")" "$@" > "$FAKE_CALLS/call_$(ls "$FAKE_CALLS" | wc -l)"
out=""
prev=""
for arg in "$@"; do
    case "$arg" in --new_root=*) out="${arg#--new_root=}" ;; esac
    [ "$prev" = --output-root ] && out="$arg"
    prev="$arg"
done
mkdir -p "$out/meta"
[ "${FAKE_FAIL:-}" = "$(basename "$0")" ] && exit 1
echo '{}' > "$out/meta/info.json"
"""

pytestmark = pytest.mark.skipif(shutil.which("bash") is None, reason="bash is not installed")


@pytest.fixture
def fake_env(tmp_path):
    names = ("subgoalvla-generate-metaworld", "lerobot-edit-dataset")
    return stand_ins(tmp_path, dict.fromkeys(names, FAKE))


def run_stage(env, out: Path, more_tasks: str, **extra_env: str) -> subprocess.CompletedProcess:
    args = [str(out), "me/mw", "reach-v3,push-v3", "30", "0.1", "2", more_tasks, "70"]
    return run_stage_function({**env, **extra_env}, "metaworld_data.sh", "metaworld_episodes", *args)


def flag(call: list[str], name: str) -> str:
    return call[call.index(name) + 1]


def test_without_more_tasks_one_recording_writes_the_training_data(fake_env, tmp_path):
    env, calls = fake_env
    assert run_stage(env, tmp_path, "").returncode == 0
    (call,) = calls_made(calls)
    assert call[0] == "subgoalvla-generate-metaworld"
    assert flag(call, "--output-root") == str(tmp_path / "raw")
    assert (flag(call, "--tasks"), flag(call, "--episodes-per-task"), flag(call, "--seed")) == (
        "reach-v3,push-v3",
        "30",
        "0",
    )
    assert (flag(call, "--action-noise"), flag(call, "--workers")) == ("0.1", "2")


def test_more_episodes_come_from_another_seed_and_are_merged_after_the_base(fake_env, tmp_path):
    env, calls = fake_env
    result = run_stage(env, tmp_path, "push-v3")
    assert result.returncode == 0, result.stderr
    base, more, merge = calls_made(calls)
    assert (flag(base, "--output-root"), flag(base, "--seed")) == (str(tmp_path / "raw_base"), "0")
    assert (flag(more, "--output-root"), flag(more, "--seed")) == (str(tmp_path / "raw_more"), "1")
    assert (flag(more, "--tasks"), flag(more, "--episodes-per-task")) == ("push-v3", "70")
    assert merge[0] == "lerobot-edit-dataset"
    assert "--operation.type=merge" in merge
    assert f"--operation.roots=[{tmp_path / 'raw_base'},{tmp_path / 'raw_more'}]" in merge
    assert (tmp_path / "raw" / "meta" / "info.json").is_file()
    assert not (tmp_path / "raw.merging").exists()


def test_a_failed_merge_leaves_no_training_data_and_a_rerun_only_merges(fake_env, tmp_path):
    env, calls = fake_env
    assert run_stage(env, tmp_path, "push-v3", FAKE_FAIL="lerobot-edit-dataset").returncode != 0
    assert not (tmp_path / "raw").exists()
    assert len(calls_made(calls)) == 3

    assert run_stage(env, tmp_path, "push-v3").returncode == 0
    assert [call[0] for call in calls_made(calls)[3:]] == ["lerobot-edit-dataset"]
    assert (tmp_path / "raw" / "meta" / "info.json").is_file()


def test_finished_training_data_is_not_recorded_again(fake_env, tmp_path):
    env, calls = fake_env
    (tmp_path / "raw" / "meta").mkdir(parents=True)
    (tmp_path / "raw" / "meta" / "info.json").write_text("{}")
    assert run_stage(env, tmp_path, "push-v3").returncode == 0
    assert calls_made(calls) == []
