"""Fixtures of the Meta-World tests: skip (one line) where Meta-World or MuJoCo rendering is missing, and one
generated reach-v3 episode shared by the tests of a session."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from lerobot_subgoalvla.metaworld import generate as gen
from lerobot_subgoalvla.metaworld import tasks

REPO_ID = "test/metaworld_reach"


@pytest.fixture(scope="session")
def metaworld_renders() -> None:
    """Skip (one line) unless Meta-World is installed and LeRobot's Meta-World env renders a frame."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    try:
        tasks.require_metaworld()
    except RuntimeError as error:
        pytest.skip(f"Meta-World unavailable: {error}")
    from lerobot_subgoalvla.metaworld.record import MetaworldRecorder

    try:
        with MetaworldRecorder("reach-v3") as recorder:
            obs, _ = recorder.env.reset(seed=0)
            assert obs["pixels"].shape == (480, 480, 3)
    except Exception as error:  # noqa: BLE001 - any GL/MuJoCo failure means "cannot render here"
        pytest.skip(f"MuJoCo cannot render here (MUJOCO_GL={os.environ['MUJOCO_GL']}): {error}")


@pytest.fixture(scope="session")
def generated(metaworld_renders: None, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One successful reach-v3 episode written by the command's Python entry point."""
    output = tmp_path_factory.mktemp("metaworld") / "reach"
    options = gen.GenerateOptions(("reach-v3",), episodes_per_task=1, seed=0, image_format="image")
    return gen.generate(output, REPO_ID, options, workers=1)
