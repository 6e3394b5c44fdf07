"""Generator: determinism for a seed, resume after an interruption, native validity, conversion."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from lerobot_subgoalvla.datasets_conversion import generate_calvin
from lerobot_subgoalvla.datasets_conversion.calvin_format import CalvinSplit
from lerobot_subgoalvla.datasets_conversion.calvin_play import relative_actions
from lerobot_subgoalvla.datasets_conversion.calvin_validate import validate_split
from lerobot_subgoalvla.datasets_conversion.convert_calvin import convert
from lerobot_subgoalvla.datasets_conversion.generate_calvin import SEGMENTS_DIR, GeneratorOptions, generate
from lerobot_subgoalvla.datasets_conversion.lerobot_parts import ConversionOptions

pytest.importorskip("pybullet")

OPTIONS = GeneratorOptions(
    num_tasks=2, seed=3, val_fraction=0.5, tasks_per_segment=1, static_size=64, gripper_size=64
)


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    output = tmp_path_factory.mktemp("gen") / "reference"
    generate(output, OPTIONS)
    return output


def _split_contents(split_dir: Path) -> dict:
    split = CalvinSplit(split_dir)
    ids = [i for start, end in split.segments.tolist() for i in range(start, end + 1)]
    lang = split.language()
    return {"segments": split.segments, "frames": split.load_frames(ids), "indx": lang.indx,
            "ann": lang.ann, "task": lang.task, "scene": split.scene_info}  # fmt: skip


def _assert_same(a: dict, b: dict) -> None:
    np.testing.assert_array_equal(a["segments"], b["segments"])
    np.testing.assert_array_equal(a["indx"], b["indx"])
    assert (a["ann"], a["task"], a["scene"]) == (b["ann"], b["task"], b["scene"])
    for key, value in a["frames"].items():
        np.testing.assert_array_equal(value, b["frames"][key], err_msg=key)


def test_generated_data_is_valid_native_calvin(generated: Path) -> None:
    for name in ("training", "validation"):
        split = validate_split(generated / name, require_language=False)
        assert split.scene_info == {"procedural": (0, split.num_frames - 1)}
        frames = split.load_frames(range(split.num_frames))
        assert frames["rgb_static"].shape[1:] == (64, 64, 3) and frames["rgb_gripper"].dtype == np.uint8
        # spec 1.6: actions[t][:6] is the next frame's TCP pose; rel_actions derived from it
        np.testing.assert_allclose(frames["actions"][:-1, :6], frames["robot_obs"][1:, :6])
        np.testing.assert_allclose(
            frames["rel_actions"], relative_actions(frames["actions"], frames["robot_obs"])
        )
        assert set(np.unique(frames["actions"][:, 6])) <= {-1.0, 1.0}
        assert np.abs(frames["rel_actions"]).max() <= 1.0
        lang = split.language()
        assert all(0 <= s <= e < split.num_frames for s, e in lang.indx.tolist())
    assert not (generated / ".segments").exists()


def test_interrupted_generation_resumes_to_identical_data(
    generated: Path, tmp_path: Path, monkeypatch
) -> None:
    output = tmp_path / "resumed"
    real = generate_calvin.generate_segment
    calls: list[int] = []

    def crash_on_second(job):
        calls.append(job.index)
        if job.index == 1:
            raise RuntimeError("simulated crash")
        return real(job)

    monkeypatch.setattr(generate_calvin, "generate_segment", crash_on_second)
    with pytest.raises(RuntimeError, match="simulated crash"):
        generate(output, OPTIONS)
    assert (output / ".segments" / "segment-000000").is_dir() and not (output / "training").exists()
    calls.clear()
    monkeypatch.setattr(generate_calvin, "generate_segment", lambda job: calls.append(job.index) or real(job))
    generate(output, OPTIONS)
    assert calls == [1]  # the finished segment was skipped
    for name in ("training", "validation"):
        _assert_same(_split_contents(output / name), _split_contents(generated / name))
    with pytest.raises(FileExistsError, match="already holds a generated dataset"):
        generate(output, OPTIONS)


def test_generated_data_converts(generated: Path, tmp_path: Path) -> None:
    options = ConversionOptions(image_format="image", mode="all")
    out = convert(generated, "local/gen", tmp_path / "converted", split="both", options=options, verify=True)
    total = sum(CalvinSplit(generated / n).num_frames for n in ("training", "validation"))
    assert out["training"].num_frames + out["validation"].num_frames == total


def test_option_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="is one segment, .* or pass --val-fraction 0"):
        GeneratorOptions(num_tasks=1, seed=0, val_fraction=0.1)
    with pytest.raises(ValueError, match="val-fraction"):
        GeneratorOptions(num_tasks=4, seed=0, val_fraction=1.5)
    (tmp_path / "out" / ".segments" / "segment-000000").mkdir(parents=True)  # a finished segment to protect
    (tmp_path / "out" / ".segments" / "options.json").write_text("{}")
    with pytest.raises(ValueError, match="other options"):
        generate(tmp_path / "out", OPTIONS)


@pytest.mark.calvin_assets
@pytest.mark.parametrize("scene", ["calvin_A", "calvin_B", "calvin_C", "calvin_D"])
def test_quirk_table_matches_simulation_slot_order(scene: str, calvin_assets_dir: Path) -> None:
    from lerobot_subgoalvla.datasets_conversion.calvin_quirks import block_order_of
    from lerobot_subgoalvla.envs.calvin.sim.simulation import CalvinSimulation

    sim = CalvinSimulation(scene, calvin_assets_dir, cameras=False)
    try:
        slots = tuple(name.removeprefix("block_") for name in sim.block_names)
    finally:
        sim.close()
    opts = GeneratorOptions(
        num_tasks=2, seed=0, scene=scene, assets_dir=str(calvin_assets_dir), val_fraction=0.0
    )
    assert opts.scene_name == scene.replace("calvin_", "calvin_scene_")
    assert slots == block_order_of(opts.scene_name)


@pytest.mark.slow
def test_worker_count_does_not_change_the_data(generated: Path, tmp_path: Path) -> None:
    generate(tmp_path / "two_workers", OPTIONS, workers=2)
    for name in ("training", "validation"):
        _assert_same(_split_contents(tmp_path / "two_workers" / name), _split_contents(generated / name))


def test_task_filter_is_validated_and_recorded(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="Unknown CALVIN task 'open_the_drawer'"):
        GeneratorOptions(num_tasks=4, seed=0, tasks=("open_drawer", "open_the_drawer"))
    with pytest.raises(ValueError, match="at least one"):
        GeneratorOptions(num_tasks=4, seed=0, tasks=())
    args = generate_calvin.parse_args(["--output", "x", "--num-tasks", "4", "--seed", "0",
                                       "--tasks", "open_drawer, close_drawer"])  # fmt: skip
    assert args.tasks == ("open_drawer", "close_drawer")
    with pytest.raises(ValueError, match="argument --tasks: Unknown CALVIN task 'nope'"):
        generate_calvin.parse_args(["--output", "x", "--num-tasks", "4", "--seed", "0", "--tasks", "nope"])


def test_task_filter_limits_what_the_expert_plays(tmp_path: Path) -> None:
    options = GeneratorOptions(num_tasks=2, seed=5, val_fraction=0.0, tasks_per_segment=2, static_size=32,
                               gripper_size=32, tasks=("turn_on_led", "turn_off_led"))  # fmt: skip
    output = generate(tmp_path / "led", options)
    tasks = CalvinSplit(output["training"]).language().task
    assert len(tasks) > 0 and set(tasks) <= {"turn_on_led", "turn_off_led"}
    generate_calvin._check_options(tmp_path / "again" / ".segments", options)  # tuples round-trip via JSON
    generate_calvin._check_options(tmp_path / "again" / ".segments", options)


def test_fewer_attempts_than_asked_for_are_reported(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    # once the LED is on, turn_on_led is infeasible: the segment of 2 ends after its first attempt
    options = GeneratorOptions(num_tasks=2, seed=0, val_fraction=0.0, tasks_per_segment=2, static_size=16,
                               gripper_size=16, tasks=("turn_on_led",))  # fmt: skip
    with caplog.at_level(logging.WARNING, logger=generate_calvin.__name__):
        generate(tmp_path / "led", options)
    assert "attempted 1 of the 2 tasks asked for" in caplog.text
    assert "--tasks-per-segment 1" in caplog.text


def test_egl_renderer_generates_frames_like_calvins_data(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="--renderer='vulkan' is not valid; use one of: tiny, egl"):
        GeneratorOptions(num_tasks=2, seed=0, renderer="vulkan")
    args = generate_calvin.parse_args(
        ["--output", "x", "--num-tasks", "1", "--seed", "0", "--renderer", "egl"]
    )
    assert args.renderer == "egl"
    common = {"num_tasks": 1, "seed": 3, "val_fraction": 0.0, "tasks_per_segment": 1, "static_size": 32,
              "gripper_size": 16, "tasks": ("turn_on_led",)}  # fmt: skip
    frames = {}
    for renderer in ("tiny", "egl"):
        output = generate(tmp_path / renderer, GeneratorOptions(**common, renderer=renderer))
        split = CalvinSplit(output["training"])
        first = int(split.segments[0][0])
        frames[renderer] = split.load_frames([first], keys=("rgb_static",))["rgb_static"][0].astype(float)
    assert frames["egl"].std() > 5 and np.abs(frames["egl"] - frames["tiny"]).mean() > 1.0


def test_an_unrelated_split_folder_in_output_is_refused(tmp_path: Path) -> None:
    (tmp_path / "out" / "training").mkdir(parents=True)
    (tmp_path / "out" / "training" / "mine.txt").write_text("not generated")
    options = GeneratorOptions(num_tasks=1, seed=0, val_fraction=0.0, tasks_per_segment=1, static_size=16,
                               gripper_size=16, tasks=("turn_on_led",))  # fmt: skip
    with pytest.raises(FileExistsError, match="already has training/ from something else"):
        generate(tmp_path / "out", options)
    assert (tmp_path / "out" / "training" / "mine.txt").read_text() == "not generated"


def test_cli_failures_are_one_line(tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch) -> None:
    import logging

    (tmp_path / "a_file").write_text("x")
    argv = ["--num-tasks", "1", "--seed", "0", "--val-fraction", "0", "--tasks-per-segment", "1",
            "--static-size", "16", "--gripper-size", "16", "--tasks", "turn_on_led"]  # fmt: skip
    for output, exception, code, text in [
        (tmp_path / "a_file" / "out", None, 1, "a_file"),  # an output below a file: NotADirectoryError
        (tmp_path / "fine", KeyboardInterrupt, 130, "rerun the same command to continue"),
    ]:
        if exception is not None:

            def interrupted(*args, error=exception, **kwargs):  # noqa: ANN002, ANN003, ANN202
                raise error()

            monkeypatch.setattr(generate_calvin, "generate", interrupted)
        caplog.clear()
        with caplog.at_level(logging.ERROR), pytest.raises(SystemExit) as info:
            generate_calvin.main(["--output", str(output), *argv])
        assert info.value.code == code
        errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
        assert len(errors) == 1 and "\n" not in errors[0] and text in errors[0]


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"max_steps_per_task": 0}, "--max-steps-per-task must be >= 1"),
        ({"static_size": 0}, "--static-size must be >= 1"),
        ({"scene": "calvin_D", "assets_dir": "/nonexistent"}, "CALVIN asset missing"),
    ],
)
def test_options_are_checked_before_anything_is_written(tmp_path: Path, changes: dict, message: str) -> None:
    base = {"num_tasks": 1, "seed": 0, "val_fraction": 0.0, "tasks_per_segment": 1, "tasks": ("turn_on_led",)}
    with pytest.raises((ValueError, FileNotFoundError), match=message):
        generate(tmp_path / "out", GeneratorOptions(**{**base, **changes}))
    assert not (tmp_path / "out").exists()  # the corrected rerun is not blocked by a half-written output


SMALL = [
    "--static-size",
    "16",
    "--gripper-size",
    "16",
    "--tasks",
    "turn_on_led",
    "--max-steps-per-task",
    "60",
]


def _main_fails(argv: list[str], caplog: pytest.LogCaptureFixture) -> str:
    """The generator CLI on ``argv``: exit 1 and exactly one one-line ERROR record, returned."""
    import logging

    caplog.clear()
    with caplog.at_level(logging.ERROR), pytest.raises(SystemExit) as info:
        generate_calvin.main(argv)
    assert info.value.code == 1
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1 and "\n" not in errors[0], errors
    return errors[0]


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--num-tasks", "0", "--seed", "0"], "--num-tasks must be >= 1, got 0"),
        (["--num-tasks", "-3", "--seed", "0"], "--num-tasks must be >= 1, got -3"),
        (
            ["--num-tasks", "2", "--seed", "0", "--val-fraction", "0", "--workers", "0"],
            "--workers must be >= 1, got 0",
        ),
        (["--num-tasks", "2", "--seed", "0", "--tasks-per-segment", "0"], "--tasks-per-segment must be >= 1"),
        (["--num-tasks", "2", "--seed", "-1", "--val-fraction", "0"], "--seed must be >= 0, got -1"),
        # the default segment size (8) makes 4 tasks one segment: no room for a validation split
        (["--num-tasks", "4", "--seed", "0"], "--num-tasks 4 with --tasks-per-segment 8 is one segment"),
        (["--num-tasks", "four", "--seed", "0"], "argument --num-tasks: invalid int value: 'four'"),
        (["--num-tasks", "2"], "the following arguments are required: --seed"),
    ],
    ids=[
        "num-tasks-0",
        "num-tasks-negative",
        "workers-0",
        "tasks-per-segment-0",
        "seed-negative",
        "one-segment-with-validation",
        "num-tasks-not-a-number",
        "seed-missing",
    ],  # fmt: skip
)
def test_bad_counts_are_one_line_before_anything_is_written(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, flags: list[str], message: str
) -> None:
    assert message in _main_fails(["--output", str(tmp_path / "out"), *SMALL, *flags], caplog)
    assert not (tmp_path / "out").exists()


def test_zero_validation_fraction_makes_a_training_split_only(tmp_path: Path) -> None:
    argv = [
        "--output",
        str(tmp_path / "out"),
        *SMALL,
        "--num-tasks",
        "2",
        "--seed",
        "0",
        "--val-fraction",
        "0",
    ]
    generate_calvin.main(argv)
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["generator_options.json", "training"]
    validate_split(tmp_path / "out" / "training", require_language=False)


def test_a_run_stopped_before_its_first_segment_does_not_block_other_options(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C before any segment finished leaves only options.json: a rerun with other options proceeds."""
    real = generate_calvin.generate_segment

    def interrupted(job):  # noqa: ANN202
        raise KeyboardInterrupt

    options = GeneratorOptions(num_tasks=1, seed=0, val_fraction=0.0, tasks_per_segment=1, static_size=16,
                               gripper_size=16, max_steps_per_task=60, tasks=("turn_on_led",))  # fmt: skip
    monkeypatch.setattr(generate_calvin, "generate_segment", interrupted)
    with pytest.raises(KeyboardInterrupt):
        generate(tmp_path / "out", options)
    monkeypatch.setattr(generate_calvin, "generate_segment", real)
    fixed = GeneratorOptions(**{**options.__dict__, "seed": 1})
    assert generate(tmp_path / "out", fixed)["training"].is_dir()


def _generator_command(output: Path) -> list[str]:
    import sys

    return [sys.executable, "-m", "lerobot_subgoalvla.datasets_conversion.generate_calvin", "--output",
            str(output), "--num-tasks", "8", "--seed", "4", "--tasks-per-segment", "1", "--val-fraction",
            "0.25", "--static-size", "32", "--gripper-size", "16"]  # fmt: skip


def _run_until(argv: list[str], ready, what: str) -> None:
    """Start ``argv``, SIGKILL it as soon as ``ready()`` holds; fail if it ended before that."""
    import os
    import signal
    import subprocess
    import sys
    import time

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path), "OMP_NUM_THREADS": "1"}
    process = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while not ready() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    process.send_signal(signal.SIGKILL)
    assert process.wait() == -signal.SIGKILL, f"the run ended before {what}"


def test_sigkill_mid_generation_then_rerun_gives_the_uninterrupted_data(tmp_path: Path) -> None:
    """Killed twice (after segment 1, then after segment 5 of the rerun), the third run finishes: the native
    files equal those of one uninterrupted run, and no scratch folder is left."""
    killed, segments = tmp_path / "killed", tmp_path / "killed" / SEGMENTS_DIR
    _run_until(_generator_command(killed), lambda: (segments / "segment-000001").is_dir(), "segment 1")
    _run_until(_generator_command(killed), lambda: (segments / "segment-000005").is_dir(), "segment 5")
    assert not (killed / "training").exists()
    generate_calvin.main(_generator_command(killed)[3:])
    generate_calvin.main(_generator_command(tmp_path / "reference")[3:])
    for name in ("training", "validation"):
        _assert_same(_split_contents(killed / name), _split_contents(tmp_path / "reference" / name))
    assert sorted(p.name for p in killed.iterdir()) == ["generator_options.json", "training", "validation"]


def test_balanced_starts_open_segments_with_every_task_in_turn() -> None:
    tasks = ("open_drawer", "lift_red_block_table", "push_pink_block_left", "turn_on_led")
    opts = GeneratorOptions(num_tasks=16, seed=3, tasks_per_segment=2, tasks=tasks, balanced_starts=True)
    firsts = [opts.first_task(i) for i in range(len(opts.segment_tasks()))]  # 8 segments: two cycles
    assert sorted(firsts[:4]) == sorted(tasks) and firsts[4:] == firsts[:4]
    assert GeneratorOptions(num_tasks=16, seed=3, tasks=tasks).first_task(0) is None  # default: random
    reseeded = GeneratorOptions(num_tasks=16, seed=4, tasks_per_segment=2, tasks=tasks, balanced_starts=True)
    assert sorted(reseeded.first_task(i) for i in range(4)) == sorted(tasks)
