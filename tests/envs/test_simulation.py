"""CalvinSimulation: determinism, reset from state, action semantics, cameras, info, errors (docs/calvin.md
1.4-3.8)."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_subgoalvla.envs.calvin.evaluation.chain_scene import EVAL_ROBOT_OBS
from lerobot_subgoalvla.envs.calvin.sim.simulation import CalvinSimulation


def eval_scene_obs() -> np.ndarray:
    """A chain-style scene_obs: slider left, drawer open, lightbulb on (switch up), LED on, blocks placed."""
    obs = np.zeros(24)
    obs[0], obs[1], obs[3], obs[4], obs[5] = 0.28, 0.22, 0.088, 1, 1
    obs[6:12] = [0.0500000896, -0.120000177, 0.459990009, 0, 0, 1.3]  # red on the table
    obs[12:18] = [0.070341633, 0.0924044687, 0.460990009, 0, 0, 1.6]  # blue in the right cabinet half
    obs[18:24] = [0.229995412, -0.11999514, 0.45999001, 0, 0, 1.9]  # pink on the table
    return obs


@pytest.fixture(scope="module")
def sim():
    simulation = CalvinSimulation("procedural", static_size=48, gripper_size=32)
    yield simulation
    simulation.close()


def _rollout(simulation: CalvinSimulation, seed: int) -> tuple[np.ndarray, np.ndarray, dict]:
    simulation.reset(np_random=np.random.default_rng(seed))
    for t in range(6):
        simulation.step(np.array([0.5, -0.3, -0.4, 0.1, 0.0, -0.2, 1.0 if t < 3 else -1.0]))
    return simulation.robot_obs(), simulation.scene_obs(), simulation.render_cameras()


def test_same_seed_same_rollout_and_images(sim):
    other = CalvinSimulation("procedural", static_size=48, gripper_size=32)
    try:
        robot_a, scene_a, images_a = _rollout(sim, seed=3)
        robot_b, scene_b, images_b = _rollout(other, seed=3)
        _, scene_c, _ = _rollout(other, seed=4)
    finally:
        other.close()
    np.testing.assert_array_equal(robot_a, robot_b)
    np.testing.assert_array_equal(scene_a, scene_b)
    for key in ("static", "gripper"):
        np.testing.assert_array_equal(images_a[key], images_b[key])
    assert not np.allclose(scene_a[6:], scene_c[6:]), "a different seed must place the blocks differently"


def test_reset_from_robot_and_scene_obs(sim):
    scene_obs = eval_scene_obs()
    sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=scene_obs)
    robot_obs = sim.robot_obs()
    np.testing.assert_allclose(robot_obs[7:14], EVAL_ROBOT_OBS[7:14], atol=1e-3)
    assert robot_obs[6] == pytest.approx(0.08, abs=1e-3)
    got = sim.scene_obs()
    np.testing.assert_allclose(got[:6], scene_obs[:6], atol=1e-3)
    for slot in range(3):
        np.testing.assert_allclose(
            got[6 + 6 * slot : 9 + 6 * slot], scene_obs[6 + 6 * slot : 9 + 6 * slot], atol=2e-3
        )
    # The measured TCP pose becomes the target (spec 3.8), so a zero action holds the arm still.
    np.testing.assert_allclose(sim.robot.target_pos, robot_obs[:3], atol=1e-5)
    sim.step(np.array([0, 0, 0, 0, 0, 0, 1.0]))
    np.testing.assert_allclose(sim.robot_obs()[:3], robot_obs[:3], atol=2e-3)


def test_reset_keeps_previous_gripper_command(sim):
    """CALVIN quirk (spec 3.8): robot_obs[14] is not restored by reset."""
    sim.reset(np_random=np.random.default_rng(0))
    sim.step(np.array([0, 0, 0, 0, 0, 0, -1.0]))
    sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=eval_scene_obs())
    assert sim.robot_obs()[14] == -1
    assert sim.robot_obs()[6] == pytest.approx(0.08, abs=1e-3)


def test_relative_action_moves_tcp_two_cm_per_step(sim):
    sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=eval_scene_obs())
    start = sim.robot_obs()[:3]
    for _ in range(5):
        sim.step(np.array([1.0, 0, 0, 0, 0, 0, 1]))
    for _ in range(6):
        sim.step(np.array([0.0, 0, 0, 0, 0, 0, 1]))
    delta = sim.robot_obs()[:3] - start
    assert delta[0] == pytest.approx(0.10, abs=0.01)
    assert np.abs(delta[1:]).max() < 0.01


def test_target_pose_winds_up_and_actions_are_clipped(sim):
    sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=eval_scene_obs())
    target0 = sim.robot.target_pos.copy()
    for _ in range(40):
        sim.step(np.array([5.0, 0, 0, 0, 0, 0, 1]))  # clipped to 1 -> 0.02 m per step
    assert sim.robot.target_pos[0] - target0[0] == pytest.approx(0.8, abs=1e-9)
    reach = sim.robot_obs()[0] - target0[0]
    assert reach < 0.7, "the arm cannot follow a 0.8 m target: the target wound up beyond the TCP"


def test_gripper_closes_within_a_few_steps_and_is_binarised(sim):
    sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=eval_scene_obs())
    widths = []
    for _ in range(12):
        sim.step(np.array([0, 0, 0, 0, 0, 0, -0.2]))  # <= 0 -> close
        widths.append(sim.robot_obs()[6])
    steps_to_close = next(i + 1 for i, w in enumerate(widths) if w < 1e-3)
    assert 4 <= steps_to_close <= 10
    assert sim.robot_obs()[14] == -1
    sim.step(np.array([0, 0, 0, 0, 0, 0, 0.3]))  # > 0 -> open
    assert sim.robot_obs()[14] == 1


def test_caller_action_is_not_modified(sim):
    """calvin_env 1431a46 scaled the caller's array in place; we copy (797142c behaviour)."""
    sim.reset(np_random=np.random.default_rng(0))
    action = np.array([0.5, 2.0, -0.3, 0.1, 0.0, 0.0, 0.7])
    sim.step(action)
    np.testing.assert_array_equal(action, [0.5, 2.0, -0.3, 0.1, 0.0, 0.0, 0.7])


def test_absolute_action_mode_reaches_pose():
    with CalvinSimulation("procedural", cameras=False, action_mode="absolute") as sim:
        sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=eval_scene_obs())
        start = sim.robot_obs()
        goal = start[:6] + np.array([0.05, 0.03, -0.04, 0, 0, 0])
        for _ in range(15):
            sim.step(np.concatenate([goal, [1.0]]))
        np.testing.assert_allclose(sim.robot_obs()[:3], goal[:3], atol=5e-3)


def test_camera_images(sim):
    sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=eval_scene_obs())
    images = sim.render_cameras()
    assert images["static"].shape == (48, 48, 3) and images["gripper"].shape == (32, 32, 3)
    for image in images.values():
        assert image.dtype == np.uint8
        assert image.std() > 5, "a rendered scene is not a constant image"
    with (
        CalvinSimulation("procedural", cameras=False) as blind,
        pytest.raises(RuntimeError, match="cameras=False"),
    ):
        blind.render_cameras()


def test_info_structure(sim):
    sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=eval_scene_obs())
    sim.step(np.array([0, 0, -1.0, 0, 0, 0, 1]))
    info = sim.get_info()
    robot = info["robot_info"]
    assert set(robot) == {
        "tcp_pos",
        "tcp_orn",
        "gripper_opening_width",
        "arm_joint_states",
        "gripper_action",
        "uid",
        "contacts",
    }
    assert robot["uid"] == 0 and len(robot["arm_joint_states"]) == 7
    scene = info["scene_info"]
    assert set(scene) == {"fixed_objects", "movable_objects", "doors", "lights", "buttons", "switches"}
    table = scene["fixed_objects"]["table"]
    assert table["uid"] == 5
    assert table["links"] == {
        "base_link": -1,
        "button_link": 0,
        "switch_link": 1,
        "slide_link": 2,
        "drawer_link": 3,
        "led_link": 4,
        "light_link": 5,
        "plank_link": 6,
    }
    assert list(scene["movable_objects"]) == ["block_red", "block_blue", "block_pink"]
    assert [b["uid"] for b in scene["movable_objects"].values()] == [2, 3, 4]
    red = scene["movable_objects"]["block_red"]
    assert set(red) == {"current_pos", "current_orn", "current_lin_vel", "current_ang_vel", "contacts", "uid"}
    assert len(red["current_orn"]) == 4
    # the red block rests on the table: its contacts name the table body and its base link
    assert any(c[2] == 5 and c[4] == -1 for c in red["contacts"])
    assert scene["doors"]["base__drawer"]["current_state"] == pytest.approx(0.22, abs=1e-3)
    assert scene["lights"] == {"lightbulb": {"logical_state": 1}, "led": {"logical_state": 1}}
    assert scene["buttons"]["base__button"]["logical_state"] == 1  # 797142c: button state := LED state
    assert scene["switches"]["base__switch"]["logical_state"] == 1  # re-derived from the raised switch


def test_two_simulations_are_independent(sim):
    with CalvinSimulation("procedural", cameras=False) as other:
        other.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=eval_scene_obs())
        sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=eval_scene_obs())
        before = other.robot_obs()
        for _ in range(5):
            sim.step(np.array([0, 1.0, 0, 0, 0, 0, -1]))
        np.testing.assert_array_equal(other.robot_obs(), before)
        assert not np.allclose(sim.robot_obs()[:3], before[:3], atol=0.02)


@pytest.mark.parametrize(
    ("action", "match"),
    [
        (np.zeros(6), r"shape \(7,\)"),
        (np.array([0, 0, np.nan, 0, 0, 0, 1]), "finite"),
        ([0, 0, 0, np.inf, 0, 0, 1], "finite"),
    ],
)
def test_bad_action_raises(sim, action, match):
    sim.reset(np_random=np.random.default_rng(0))
    with pytest.raises(ValueError, match=match):
        sim.step(action)


def test_bad_reset_and_construction_raise(sim):
    with pytest.raises(ValueError, match="robot_obs"):
        sim.reset(robot_obs=np.zeros(14), scene_obs=eval_scene_obs())
    bad_scene = eval_scene_obs()
    bad_scene[7] = np.nan
    with pytest.raises(ValueError, match="scene_obs"):
        sim.reset(scene_obs=bad_scene)
    with pytest.raises(ValueError, match="np_random"):
        sim.reset()
    with pytest.raises(ValueError, match="scene must be one of"):
        CalvinSimulation("calvin_E")
    with pytest.raises(ValueError, match="action_mode"):
        CalvinSimulation(action_mode="joint")
    with pytest.raises(ValueError, match="assets_dir"):
        CalvinSimulation("calvin_D")
