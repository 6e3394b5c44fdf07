"""Scene: table links and joints, button/switch/light logic, geometry, random reset, CALVIN scenes
(docs/calvin.md 3)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pybullet
import pytest

from lerobot_subgoalvla.envs.calvin.evaluation.chain_scene import EVAL_ROBOT_OBS
from lerobot_subgoalvla.envs.calvin.sim.simulation import CalvinSimulation

HOLD_OPEN = np.array([0, 0, 0, 0, 0, 0, 1.0])


@pytest.fixture(scope="module")
def sim():
    simulation = CalvinSimulation("procedural", cameras=False)
    yield simulation
    simulation.close()


def _scene_obs(slide=0.0, drawer=0.0, button=0.0, switch=0.0, bulb=0, led=0, blocks=None) -> np.ndarray:
    obs = np.zeros(24)
    obs[:6] = [slide, drawer, button, switch, bulb, led]
    blocks = blocks or [(0.05, -0.12, 0.46), (0.07, 0.092, 0.461), (0.23, -0.12, 0.46)]
    for slot, pos in enumerate(blocks):
        obs[6 + 6 * slot : 9 + 6 * slot] = pos
        obs[11 + 6 * slot] = np.pi / 2
    return obs


def test_procedural_table_matches_calvin_links_and_joints(sim):
    c, table = sim.client, sim.scene.table_uid
    expected = {
        0: ("base__button", "button_link", pybullet.JOINT_PRISMATIC, 0.02),
        1: ("base__switch", "switch_link", pybullet.JOINT_PRISMATIC, 0.088),
        2: ("base__slide", "slide_link", pybullet.JOINT_PRISMATIC, 0.28),
        3: ("base__drawer", "drawer_link", pybullet.JOINT_PRISMATIC, 0.22),
        4: ("base__led", "led_link", pybullet.JOINT_FIXED, None),
        5: ("base__light", "light_link", pybullet.JOINT_FIXED, None),
        6: ("base__plank", "plank_link", pybullet.JOINT_FIXED, None),
    }
    assert c.getNumJoints(table) == 7
    for index, (joint, link, joint_type, upper) in expected.items():
        info = c.getJointInfo(table, index)
        assert (info[1].decode(), info[12].decode(), info[2]) == (joint, link, joint_type)
        if upper is not None:
            assert info[8:10] == pytest.approx((0.0, upper), abs=1e-9)
    # world joint frames of scene D (spec 3.2 table)
    frames = {
        0: (-0.12, -0.12, 0.46),
        1: (0.30, 0.061, 0.495),
        2: (-0.10, 0.075, 0.535),
        3: (0.18, 0.0, 0.32),
    }
    sim.reset(scene_obs=_scene_obs())
    for index, pos in frames.items():
        np.testing.assert_allclose(c.getLinkState(table, index)[4], pos, atol=5e-4)


def test_button_rising_edge_toggles_led(sim):
    sim.reset(scene_obs=_scene_obs())
    c, table, scene = sim.client, sim.scene.table_uid, sim.scene
    leds = []
    for joint_value in (0.015, 0.015, 0.0, 0.018, 0.0):  # press, hold, release, press, release
        c.resetJointState(table, 0, joint_value)
        scene.step()
        leds.append(scene.light_states["led"])
    assert leds == [1, 1, 1, 0, 0]
    assert scene.observation()[5] == 0


def test_button_springs_back_and_physical_press_turns_led_on(sim):
    sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=_scene_obs())
    sim.client.resetJointState(sim.scene.table_uid, 0, 0.02)
    sim.step(HOLD_OPEN)
    assert sim.scene_obs()[5] == 1, "a pressed button turns the LED on after the step"
    for _ in range(10):
        sim.step(HOLD_OPEN)
    assert sim.scene_obs()[2] < 0.005, "the button's position motor (force 4) pushes it back up"
    assert sim.scene_obs()[5] == 1, "releasing does not toggle"


def test_switch_level_drives_lightbulb_and_friction_holds_it(sim):
    sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=_scene_obs(switch=0.088))
    assert sim.scene_obs()[4] == 0, "reset keeps the given lightbulb state until the next step"
    for _ in range(10):
        sim.step(HOLD_OPEN)
    obs = sim.scene_obs()
    assert obs[3] == pytest.approx(0.088, abs=2e-3), "joint friction holds the raised switch"
    assert obs[4] == 1
    sim.client.resetJointState(sim.scene.table_uid, 1, 0.0)
    sim.step(HOLD_OPEN)
    assert sim.scene_obs()[4] == 0
    assert sim.get_info()["scene_info"]["switches"]["base__switch"]["logical_state"] == 0


@pytest.mark.parametrize(
    ("joint", "index", "upper", "velocity"), [("drawer", 3, 0.22, 1.0), ("slide", 2, 0.28, 1.0)]
)
def test_drawer_and_slide_stop_at_their_limits(sim, joint, index, upper, velocity):
    sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=_scene_obs())
    sim.client.resetJointState(sim.scene.table_uid, index, upper - 0.02, targetVelocity=velocity)
    for _ in range(5):
        sim.step(HOLD_OPEN)
    value = sim.scene.joint_state(f"base__{joint}")
    assert upper - 0.01 < value <= upper + 3e-3


def test_blocks_rest_on_desk_shelf_and_in_drawer(sim):
    blocks = [(0.05, -0.12, 0.47), (-0.24, 0.092, 0.47), (0.18, -0.30, 0.38)]  # desk, left shelf, open drawer
    sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=_scene_obs(slide=0.0, drawer=0.22, blocks=blocks))
    for _ in range(20):
        sim.step(HOLD_OPEN)
    obs = sim.scene_obs()
    heights = obs[[8, 14, 20]]
    np.testing.assert_allclose(heights, [0.46, 0.461, 0.362], atol=3e-3)
    for slot, (x, y, _) in enumerate(blocks):
        np.testing.assert_allclose(obs[6 + 6 * slot : 8 + 6 * slot], (x, y), atol=5e-3)


def test_random_reset_uses_surfaces_without_block_contacts(sim):
    boxes = list(sim.scene.surfaces.values())
    for seed in range(4):
        sim.reset(np_random=np.random.default_rng(seed))
        obs = sim.scene_obs()
        np.testing.assert_allclose(obs[:6], 0.0, atol=1e-4, err_msg="random reset: doors closed, lights off")
        uids = list(sim.scene.block_uids.values())
        for a in range(3):
            x, y = obs[6 + 6 * a : 8 + 6 * a]
            assert any(
                lo[0] - 1e-3 <= x <= hi[0] + 1e-3 and lo[1] - 1e-3 <= y <= hi[1] + 1e-3 for lo, hi in boxes
            )
            for b in range(a + 1, 3):
                assert not sim.client.getContactPoints(bodyA=uids[a], bodyB=uids[b])


def test_handle_positions_move_with_their_joints(sim):
    sim.reset(scene_obs=_scene_obs())
    closed = {
        name: sim.scene.handle_position(name) for name in ("drawer_handle", "slide_handle", "switch_lever")
    }
    sim.reset(scene_obs=_scene_obs(slide=0.28, drawer=0.22, switch=0.088))
    np.testing.assert_allclose(
        sim.scene.handle_position("drawer_handle") - closed["drawer_handle"], (0, -0.22, 0), atol=1e-6
    )
    np.testing.assert_allclose(
        sim.scene.handle_position("slide_handle") - closed["slide_handle"], (-0.28, 0, 0), atol=1e-6
    )
    np.testing.assert_allclose(
        sim.scene.handle_position("switch_lever") - closed["switch_lever"], (0, 0.044, 0.0762), atol=1e-3
    )
    with pytest.raises(ValueError, match="unknown point"):
        sim.scene.handle_position("door_knob")


def test_missing_calvin_files_are_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="calvin_scene_D.yaml"):
        CalvinSimulation("calvin_D", assets_dir=tmp_path)


@pytest.mark.calvin_assets
def test_missing_table_urdf_is_named(calvin_assets_dir: Path, tmp_path):
    """A calvin_env tree without calvin_table_D (built from symlinks, nothing copied)."""
    (tmp_path / "conf").symlink_to(calvin_assets_dir / "conf")
    (tmp_path / "data").mkdir()
    for entry in (calvin_assets_dir / "data").iterdir():
        if entry.name != "calvin_table_D":
            (tmp_path / "data" / entry.name).symlink_to(entry)
    with pytest.raises(FileNotFoundError, match="calvin_table_D.urdf"):
        CalvinSimulation("calvin_D", assets_dir=tmp_path)


@pytest.mark.calvin_assets
def test_calvin_d_loads_with_calvin_indices_and_robot(calvin_assets_dir: Path):
    with CalvinSimulation("calvin_D", assets_dir=calvin_assets_dir, static_size=32, gripper_size=16) as sim:
        assert sim.block_names == ("block_red", "block_blue", "block_pink")
        sim.reset(robot_obs=EVAL_ROBOT_OBS, scene_obs=_scene_obs(bulb=1, switch=0.088))
        info = sim.get_info()["scene_info"]
        assert info["fixed_objects"]["table"]["uid"] == 5
        assert info["fixed_objects"]["table"]["links"]["plank_link"] == 6
        assert [b["uid"] for b in info["movable_objects"].values()] == [2, 3, 4]
        # CALVIN's TCP (link 15) at the evaluation joints is the spec's robot_obs[0:6] (spec 4.2)
        np.testing.assert_allclose(sim.robot_obs()[:3], EVAL_ROBOT_OBS[:3], atol=1e-3)
        np.testing.assert_allclose(np.cos(sim.robot_obs()[3:6] - EVAL_ROBOT_OBS[3:6]), 1.0, atol=1e-5)
        # gripper camera 0.10 m behind and 0.137 m above the TCP at this pose (spec 3.6)
        eye, _ = sim.robot.camera_pose()
        np.testing.assert_allclose(eye - sim.robot_obs()[:3], (0.0, -0.10, 0.137), atol=0.02)
        sim.step(HOLD_OPEN)
        assert sim.scene_obs()[4] == 1 and sim.scene_obs()[8] == pytest.approx(0.46, abs=3e-3)
        assert sim.render_cameras()["static"].shape == (32, 32, 3)


@pytest.mark.calvin_assets
def test_procedural_table_frames_and_handles_match_calvin_d(sim, calvin_assets_dir: Path):
    """Same link frames (position and orientation) and handle points within 2 cm as CALVIN's scene D table."""
    sim.reset(scene_obs=_scene_obs())
    with CalvinSimulation("calvin_D", assets_dir=calvin_assets_dir, cameras=False) as calvin:
        calvin.reset(scene_obs=_scene_obs())
        for link in range(7):
            ours = sim.client.getLinkState(sim.scene.table_uid, link)[4:6]
            theirs = calvin.client.getLinkState(calvin.scene.table_uid, link)[4:6]
            np.testing.assert_allclose(ours[0], theirs[0], atol=1e-5)
            assert abs(np.dot(ours[1], theirs[1])) == pytest.approx(1.0, abs=1e-6)
        for name in ("drawer_handle", "slide_handle", "button_top", "switch_lever", "led", "lightbulb"):
            np.testing.assert_allclose(
                sim.scene.handle_position(name), calvin.scene.handle_position(name), atol=0.02
            )


@pytest.mark.calvin_assets
@pytest.mark.skipif(os.environ.get("CI") == "true", reason="extra CALVIN scene load")
def test_calvin_a_slot_order(calvin_assets_dir: Path):
    with CalvinSimulation("calvin_A", assets_dir=calvin_assets_dir, cameras=False) as sim:
        assert sim.block_names == ("block_pink", "block_blue", "block_red")
        assert sim.scene.surfaces["table"][0][0] == pytest.approx(-0.2)
