"""Ghost-robot rendering of subgoal traces: visible ghosts, untouched simulation, media files."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np
import pytest
from PIL import Image

from lerobot_subgoalvla.envs.calvin.env import CalvinEnv
from lerobot_subgoalvla.visualization.ghost_robots import render_trace, write_trace_media

SIZE = 48


@pytest.fixture
def env() -> CalvinEnv:
    env = CalvinEnv(
        "lh_mtlc", chain_start=0, chain_stop=1, episode_length=10, static_size=SIZE, gripper_size=16
    )
    env.reset(seed=0)
    yield env
    env.close()


def _moved_trace(robot_obs: np.ndarray, m: int = 4) -> np.ndarray:
    trace = np.repeat(robot_obs[None].astype(np.float64), m, axis=0)  # (M, 15)
    trace[:, 7] += np.linspace(0.2, 0.8, m)  # swing the base joint further and further
    trace[:, 6] = 0.0  # closed fingers
    return trace


def test_ghosts_change_the_frame_only_where_a_ghost_is(env: CalvinEnv) -> None:
    frame = env.render()
    overlay = render_trace(env.simulation, _moved_trace(env.simulation.robot_obs()), frame)
    assert overlay.shape == frame.shape and overlay.dtype == np.uint8
    changed = np.any(overlay != frame, axis=-1)  # (H, W)
    assert changed.sum() > 20  # the ghosts are visible
    assert changed.mean() < 0.5  # and they are robots, not a global tint
    # With zero opacity nothing is drawn.
    invisible = render_trace(
        env.simulation, _moved_trace(env.simulation.robot_obs()), frame, max_alpha=0, min_alpha=0
    )
    np.testing.assert_array_equal(invisible, frame)


def test_nearer_ghosts_are_more_opaque(env: CalvinEnv) -> None:
    frame = env.render()
    trace = _moved_trace(env.simulation.robot_obs(), m=1)
    strong = render_trace(env.simulation, trace, frame, max_alpha=0.9, min_alpha=0.9)
    weak = render_trace(env.simulation, trace, frame, max_alpha=0.2, min_alpha=0.2)
    diff_strong = np.abs(strong.astype(int) - frame).sum()
    diff_weak = np.abs(weak.astype(int) - frame).sum()
    assert diff_strong > diff_weak > 0


def test_rendering_a_trace_leaves_the_simulation_untouched(env: CalvinEnv) -> None:
    twin = CalvinEnv(
        "lh_mtlc", chain_start=0, chain_stop=1, episode_length=10, static_size=SIZE, gripper_size=16
    )
    twin.reset(seed=0)
    sim = env.simulation
    before = (sim.robot_obs(), sim.scene_obs(), env.render())
    render_trace(sim, _moved_trace(sim.robot_obs()))
    # Joints, gripper and scene exactly as before. The reported TCP is pybullet's cached link transform (as
    # CALVIN reports it), which restoring the joints refreshes: it may move by the last sub-step (~1e-6 here)
    # until the next physics step, which the twin comparison below shows changes nothing.
    np.testing.assert_array_equal(sim.robot_obs()[6:], before[0][6:])
    np.testing.assert_allclose(sim.robot_obs()[:6], before[0][:6], atol=1e-4)
    np.testing.assert_array_equal(sim.scene_obs(), before[1])
    np.testing.assert_array_equal(sim.cameras.render_static(), before[2])
    # Physics continues exactly like a twin whose robot was never moved for drawing.
    action = np.array([0.5, -0.3, 0.2, 0.0, 0.0, 0.1, -1.0])
    for _ in range(5):
        obs, *_ = env.step(action)
        twin_obs, *_ = twin.step(action)
        np.testing.assert_array_equal(obs["agent_pos"], twin_obs["agent_pos"])
        np.testing.assert_array_equal(obs["environment_state"], twin_obs["environment_state"])
        np.testing.assert_array_equal(obs["pixels"]["static"], twin_obs["pixels"]["static"])
    twin.close()


@pytest.mark.parametrize(
    ("trace", "message"),
    [
        (np.zeros((4, 14)), r"shape \(M, 15\)"),
        (np.zeros((0, 15)), "M >= 1"),
        (np.full((2, 15), np.nan), "NaN"),
    ],
)
def test_bad_traces_raise(env: CalvinEnv, trace: np.ndarray, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        render_trace(env.simulation, trace)


def test_write_png_strip_and_mp4(env: CalvinEnv, tmp_path: Path) -> None:
    trace = _moved_trace(env.simulation.robot_obs())
    frames = []
    for _ in range(3):
        env.step(np.array([0.3, 0, 0, 0, 0, 0, 1.0]))
        frames.append(render_trace(env.simulation, trace))
    png = write_trace_media(frames, tmp_path / "strip.png")
    assert np.asarray(Image.open(png)).shape == (SIZE, 3 * SIZE, 3)
    mp4 = write_trace_media(frames, tmp_path / "videos" / "rollout.mp4", fps=30)
    with av.open(str(mp4)) as container:
        assert sum(1 for _ in container.decode(video=0)) == 3
    with pytest.raises(ValueError, match=r"\.mp4 \(video\) or \.png"):
        write_trace_media(frames, tmp_path / "x.gif")
