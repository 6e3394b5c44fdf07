"""The two camera renderers: TinyRenderer (default) and EGL (OpenGL, as CALVIN's data), CPU-only via Mesa."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_subgoalvla.config_error import ConfigError
from lerobot_subgoalvla.envs.calvin.configs import CalvinEnvConfig
from lerobot_subgoalvla.envs.calvin.env import CalvinEnv
from lerobot_subgoalvla.envs.calvin.sim.cameras import check_renderer
from lerobot_subgoalvla.envs.calvin.sim.simulation import CalvinSimulation

MOVE = np.array([0.5, -0.5, -0.5, 0.0, 0.0, 0.5, -1.0])


def _images(renderer: str, steps: int = 3) -> list[dict[str, np.ndarray]]:
    sim = CalvinSimulation("procedural", static_size=64, gripper_size=32, renderer=renderer)
    try:
        sim.reset(np_random=np.random.default_rng(0))
        frames = [sim.render_cameras()]
        for _ in range(steps):
            sim.step(MOVE)
            frames.append(sim.render_cameras())
        return frames
    finally:
        sim.close()


def test_egl_renders_the_scene_deterministically_and_differently_from_tiny() -> None:
    egl, again, tiny = _images("egl"), _images("egl"), _images("tiny")
    for a, b, t in zip(egl, again, tiny, strict=True):
        for camera in ("static", "gripper"):
            assert a[camera].shape == t[camera].shape and a[camera].dtype == np.uint8
            np.testing.assert_array_equal(a[camera], b[camera])  # same seed, same actions, same pixels
    static = egl[0]["static"].astype(float)
    assert static.std() > 10  # the scene, not a blank background (the plugin was loaded before the bodies)
    difference = np.abs(static - tiny[0]["static"].astype(float)).mean()
    assert 1.0 < difference < 80.0  # same scene, other lighting and shading
    assert not np.array_equal(egl[0]["gripper"], egl[-1]["gripper"])  # the gripper camera follows the arm


def test_unknown_renderer_is_refused_everywhere_with_the_allowed_values() -> None:
    with pytest.raises(ValueError, match="renderer='vulkan' is not valid; use one of: tiny, egl"):
        check_renderer("vulkan")
    with pytest.raises(ValueError, match="renderer='vulkan'"):
        CalvinSimulation("procedural", renderer="vulkan")
    with pytest.raises(ValueError, match="renderer='vulkan'"):
        CalvinEnv("open_drawer", renderer="vulkan")
    with pytest.raises(ConfigError, match="--env.renderer='vulkan' is not valid; use one of: tiny, egl"):
        CalvinEnvConfig(task="open_drawer", renderer="vulkan")


def test_env_config_passes_the_renderer_to_its_sub_envs() -> None:
    cfg = CalvinEnvConfig(task="open_drawer", renderer="egl", static_image_size=32, gripper_image_size=16)
    assert cfg.gym_kwargs["renderer"] == "egl"
    env = CalvinEnv(**{**cfg.gym_kwargs, "episode_length": 3})
    try:
        obs, _ = env.reset(seed=0)
        assert obs["pixels"]["static"].shape == (32, 32, 3) and obs["pixels"]["static"].std() > 5
        assert env.unwrapped._sim.cameras.renderer == "egl"
    finally:
        env.close()
