"""subgoalvla-generate-metaworld: published layout, bad input, determinism, resuming (docs/metaworld.md).

The recording tests need Meta-World and a MuJoCo that renders (``MUJOCO_GL=egl`` with Mesa on a CPU); they
skip with one line where either is missing. One generation (reach-v3, one episode, PNG frames) is shared by
the layout tests: about 30 s on two busy cores.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from lerobot_subgoalvla.metaworld import generate as gen
from lerobot_subgoalvla.metaworld import tasks

REPO_ID = "test/metaworld_reach"
PUBLISHED_FEATURES = {  # lerobot/metaworld_mt50 meta/info.json (codebase v3.0): key -> (dtype, shape)
    "observation.image": ("image", (480, 480, 3)),
    "observation.state": ("float32", (4,)),
    "observation.environment_state": ("float32", (39,)),
    "action": ("float32", (4,)),
    "next.reward": ("float32", (1,)),
    "next.success": ("bool", (1,)),
    "task_id": ("int16", (1,)),
}


def _dataset(root: Path):
    from lerobot.datasets import LeRobotDataset

    return LeRobotDataset(REPO_ID, root=root, video_backend="pyav")


def test_output_has_the_published_layout(generated: Path) -> None:
    dataset = _dataset(generated)
    assert dataset.meta.fps == 80
    assert dataset.meta.robot_type == "metaworld"
    assert dataset.meta.total_episodes == 1
    for key, (dtype, shape) in PUBLISHED_FEATURES.items():
        assert dataset.meta.features[key]["dtype"] == dtype, key
        assert tuple(dataset.meta.features[key]["shape"]) == shape, key
    first, last = dataset[0], dataset[len(dataset) - 1]
    assert first["task"] == "Reach a goal position"  # what LeRobot's env gives a policy at evaluation
    assert tuple(first["observation.image"].shape) == (3, 480, 480)  # channels first once loaded
    assert int(first["task_id"]) == tasks.task_id("reach-v3")
    assert bool(last["next.success"]) and not bool(first["next.success"])  # ends at the first success


def test_state_is_lerobot_agent_pos_and_actions_are_bounded(generated: Path) -> None:
    frames = _dataset(generated).hf_dataset.with_format("numpy")
    state = np.stack(frames["observation.state"])  # (T, 4)
    full = np.stack(frames["observation.environment_state"])  # (T, 39)
    np.testing.assert_allclose(state, full[:, :4], atol=1e-6)  # agent_pos = Meta-World obs[:4]
    assert np.abs(np.stack(frames["action"])).max() <= 1.0


def test_only_the_dataset_is_left(generated: Path) -> None:
    assert not generated.with_name(generated.name + ".partial").exists()
    summary = json.loads((generated / "meta" / "metaworld_generation.json").read_text())
    assert summary[0]["task"] == "reach-v3" and summary[0]["tries"] >= 1


def _run_main(args: list[str], caplog: pytest.LogCaptureFixture) -> tuple[int, list[str]]:
    caplog.clear()
    with caplog.at_level(logging.ERROR), pytest.raises(SystemExit) as exit_info:
        gen.main(args)
    return exit_info.value.code, [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]


def _args(output: Path, **overrides: str) -> list[str]:
    flags = {"--output-root": str(output), "--repo-id": REPO_ID, "--tasks": "reach-v3",
             "--episodes-per-task": "1", "--seed": "0"} | overrides  # fmt: skip
    return [item for pair in flags.items() for item in pair]


@pytest.mark.parametrize(
    ("overrides", "expected"),
    [
        ({"--tasks": "reach-v9"}, "unknown Meta-World task 'reach-v9'"),
        ({"--tasks": "drawer-open"}, "did you mean drawer-open-v3"),
        ({"--episodes-per-task": "0"}, "--episodes-per-task must be >= 1"),
        ({"--image-size": "640"}, "--image-size must be <= 480"),
        ({"--action-noise": "-0.1"}, "--action-noise must be in [0, 1]"),
        ({"--workers": "0"}, "--workers must be >= 1"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, overrides: dict, expected: str
) -> None:
    code, errors = _run_main(_args(tmp_path / "out", **overrides), caplog)
    assert code == 1 and len(errors) == 1 and expected in errors[0] and "\n" not in errors[0]
    assert list(tmp_path.iterdir()) == []


def test_existing_output_is_refused_untouched(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    output = tmp_path / "out"
    output.mkdir()
    (output / "keep.txt").write_text("mine")
    code, errors = _run_main(_args(output), caplog)
    assert code == 1 and len(errors) == 1 and "not empty" in errors[0]
    assert (
        sorted(p.name for p in tmp_path.iterdir()) == ["out"] and (output / "keep.txt").read_text() == "mine"
    )


def test_missing_metaworld_names_the_install_command(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    real = tasks.importlib.util.find_spec
    monkeypatch.setattr(
        tasks.importlib.util, "find_spec", lambda name, *a: None if name == "metaworld" else real(name, *a)
    )
    code, errors = _run_main(_args(tmp_path / "out"), caplog)
    assert code == 1 and errors == ["metaworld is not installed; pip install -e '.[metaworld]'"]
    assert list(tmp_path.iterdir()) == []


def test_task_sets_and_names() -> None:
    assert tasks.parse_tasks("mt10") == tasks.MT10 and len(tasks.MT10) == 10
    assert tasks.parse_tasks("reach-v3, mt10") == tasks.MT10  # de-duplicated, first-seen order
    assert set(tasks.MT10) <= set(tasks.known_tasks()) and len(tasks.known_tasks()) == 50
    assert tasks.task_description("drawer-open-v3") == "Open a drawer"


def test_episode_seeds_depend_on_the_options_only() -> None:
    first, rng_a = gen.attempt_seeds(0, "reach-v3", 0, 0)
    again, rng_b = gen.attempt_seeds(0, "reach-v3", 0, 0)
    assert first == again and rng_a.normal() == rng_b.normal()
    variations = [(0, "reach-v3", 0, 1), (0, "reach-v3", 1, 0), (0, "push-v3", 0, 0), (1, "reach-v3", 0, 0)]
    others = {gen.attempt_seeds(*args)[0] for args in variations}
    assert first not in others and len(others) == 4


def test_parts_split_each_task() -> None:
    opts = gen.GenerateOptions(("reach-v3", "push-v3"), episodes_per_task=25, seed=0, episodes_per_part=10)
    jobs = gen.plan_parts(opts, Path("/parts"), REPO_ID)
    assert [(j.task, j.index, j.episodes) for j in jobs] == [
        ("reach-v3", 0, 10), ("reach-v3", 1, 10), ("reach-v3", 2, 5),
        ("push-v3", 0, 10), ("push-v3", 1, 10), ("push-v3", 2, 5),
    ]  # fmt: skip


@pytest.mark.slow
def test_same_seed_same_episode_and_resume_reuses_finished_parts(
    metaworld_renders: None, tmp_path: Path
) -> None:
    """A finished part in OUTPUT.partial is merged as it is; its episodes equal a fresh recording's."""
    opts = gen.GenerateOptions(("reach-v3",), episodes_per_task=2, seed=3, episodes_per_part=1)
    output = tmp_path / "out"
    work = tmp_path / "out.partial"
    gen._check_options(work, opts, REPO_ID)
    first_part = gen.plan_parts(opts, work / "parts", REPO_ID)[0]
    summary = gen.record_part(first_part)  # as if an earlier run had stopped after this part
    marked = {**summary, "resumed": True}
    (first_part.directory / gen.SUMMARY_FILE).write_text(json.dumps(marked))
    gen.generate(output, REPO_ID, opts, workers=2)
    records = json.loads((output / "meta" / "metaworld_generation.json").read_text())
    assert records[0].get("resumed") and not records[1].get("resumed")
    fresh = gen.generate(tmp_path / "fresh", REPO_ID, opts, workers=1)
    ours, theirs = (_dataset(p).hf_dataset.with_format("numpy") for p in (output, fresh))
    np.testing.assert_array_equal(np.stack(ours["action"]), np.stack(theirs["action"]))
