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


def test_egl_devices_are_enumerated_and_a_device_that_does_not_exist_is_refused(monkeypatch) -> None:
    from lerobot_subgoalvla.envs.calvin.sim.egl_devices import egl_devices

    devices = egl_devices()
    assert devices and [d.index for d in devices] == list(range(len(devices)))
    # pybullet's plugin would end the whole process on an index it lacks; we refuse it before loading
    monkeypatch.setenv("EGL_VISIBLE_DEVICES", str(len(devices)))
    with pytest.raises(ValueError, match=f"EGL_VISIBLE_DEVICES='{len(devices)}' names no EGL device"):
        CalvinSimulation("procedural", static_size=16, gripper_size=16, renderer="egl")
    cuda = {d.cuda_index for d in devices}
    missing = next(i for i in range(64) if i not in cuda)
    monkeypatch.delenv("EGL_VISIBLE_DEVICES")
    with pytest.raises(ValueError, match=f"CUDA device {missing} is no EGL device"):
        CalvinSimulation(
            "procedural", static_size=16, gripper_size=16, renderer="egl", egl_cuda_device=missing
        )


def test_the_egl_device_of_a_cuda_gpu_is_chosen_as_calvin_env_does() -> None:
    from lerobot_subgoalvla.envs.calvin.sim.egl_devices import EglDevice, choose_index

    # an NVIDIA box whose EGL order is not the CUDA order, plus a software device
    devices = [EglDevice(0, 1, ""), EglDevice(1, 0, ""), EglDevice(2, None, "EGL_MESA_device_software")]
    assert choose_index(devices, cuda_device=0, visible=None) == 1
    assert choose_index(devices, cuda_device=1, visible="2") == 0  # the CUDA choice wins over the variable
    assert choose_index(devices, cuda_device=None, visible="2") == 2
    assert choose_index(devices, cuda_device=None, visible=None) == 0
    with pytest.raises(ValueError, match=r"EGL devices: 0 \(CUDA 1\), 1 \(CUDA 0\), 2 \(no CUDA\)"):
        choose_index(devices, cuda_device=3, visible=None)


def test_env_config_spreads_egl_workers_over_the_listed_cuda_devices() -> None:
    with pytest.raises(ConfigError, match="needs --env.renderer=egl"):
        CalvinEnvConfig(task="open_drawer", egl_cuda_devices=[0])
    with pytest.raises(ConfigError, match="non-empty list of CUDA indices"):
        CalvinEnvConfig(task="open_drawer", renderer="egl", egl_cuda_devices=[])
    cfg = CalvinEnvConfig(task="open_drawer", renderer="egl", egl_cuda_devices=[0, 1])
    views = cfg.create_envs(n_envs=3)["calvin_open_drawer"]
    shared = next(iter(views.values()))._shared
    try:
        assert [fn.keywords["egl_cuda_device"] for fn in shared.env_fns] == [0, 1, 0]
    finally:
        shared.close()
