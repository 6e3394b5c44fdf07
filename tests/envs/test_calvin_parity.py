"""Parity with calvin_env where it differs from the obvious choice (docs/calvin.md 3.1, 3.7).

calvin_env runs contact with Bullet's default ``deterministicOverlappingPairs`` (its load() resets the
simulation after setting 1), and reads the TCP and the gripper camera pose from the link transform pybullet
cached at the start of the last physics sub-step. These tests pin those formulas; they need no calvin_env.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pybullet
import pytest

from lerobot_subgoalvla.envs.calvin.expert.scripted_expert import ScriptedExpert
from lerobot_subgoalvla.envs.calvin.expert.start_states import sample_start_state
from lerobot_subgoalvla.envs.calvin.sim.robot import CAMERA_FROM_HAND, HAND_LINK
from lerobot_subgoalvla.envs.calvin.sim.simulation import CalvinSimulation

MOVE = np.array([1.0, 0.0, -1.0, 0.0, 0.0, 1.0, 1.0])  # full-speed relative action: the arm moves


@pytest.fixture
def moving_sim() -> Iterator[CalvinSimulation]:
    """A procedural simulation whose arm has moved at full speed for 5 steps (and is still moving)."""
    sim = CalvinSimulation("procedural", static_size=16, gripper_size=16)
    sim.reset(np_random=np.random.default_rng(0))
    for _ in range(5):
        sim.step(MOVE)
    yield sim
    sim.close()


def _expert_scene_obs(task: str, seed: int, flag: int | None, steps: int = 120) -> np.ndarray:
    """scene_obs after the expert's first ``steps`` steps of ``task``; ``flag`` overrides the contact flag."""
    sim = CalvinSimulation("procedural", cameras=False)
    try:
        if flag is not None:
            sim.client.setPhysicsEngineParameter(deterministicOverlappingPairs=flag)
        sample_start_state(task, sim, np.random.default_rng(seed))
        expert = ScriptedExpert(sim, task, np.random.default_rng(seed))
        for _ in range(steps):
            if expert.done:
                break
            sim.step(expert.act())
        return sim.scene_obs().copy()
    finally:
        sim.close()


@pytest.mark.parametrize(("task", "seed"), [("rotate_red_block_right", 0), ("stack_block", 2)])
def test_contact_determinism_flag_is_calvins_effective_zero(task: str, seed: int) -> None:
    """pybullet cannot read the flag back; contact-rich expert runs show which one is in force."""
    ours = _expert_scene_obs(task, seed, flag=None)
    np.testing.assert_array_equal(ours, _expert_scene_obs(task, seed, flag=0))
    assert not np.array_equal(ours, _expert_scene_obs(task, seed, flag=1))  # the flag matters here


def test_reported_tcp_is_the_cached_transform_one_substep_behind(moving_sim: CalvinSimulation) -> None:
    sim = moving_sim
    robot, c = sim.robot, sim.client
    obs, info_tcp = sim.robot_obs(), np.array(sim.get_info()["robot_info"]["tcp_pos"])
    cached = c.getLinkState(robot.uid, robot.spec.tcp_link)  # CALVIN's call
    # computeForwardKinematics=True refreshes pybullet's cache: query it last
    current = c.getLinkState(robot.uid, robot.spec.tcp_link, computeForwardKinematics=True)
    np.testing.assert_array_equal(obs[0:3], np.array(cached[0]))
    np.testing.assert_array_equal(obs[3:6], np.array(c.getEulerFromQuaternion(cached[1])))
    lag = np.linalg.norm(np.array(current[0]) - obs[0:3])
    assert 1e-4 < lag < 5e-3  # moving at full speed: about a millimetre behind the joints
    np.testing.assert_array_equal(info_tcp, obs[0:3])


def test_reset_target_is_the_true_tcp() -> None:
    sim = CalvinSimulation("procedural", static_size=16, gripper_size=16)
    try:
        sim.reset(np_random=np.random.default_rng(0))
        robot, c = sim.robot, sim.client
        current = c.getLinkState(robot.uid, robot.spec.tcp_link, computeForwardKinematics=True)
        np.testing.assert_allclose(
            robot.target_pos, current[0], atol=1e-5
        )  # reset ends with one physics step
    finally:
        sim.close()


def test_gripper_camera_is_posed_from_the_cached_transform(moving_sim: CalvinSimulation) -> None:
    sim = moving_sim
    robot, c = sim.robot, sim.client
    position, rotation = robot.camera_pose()
    link = robot.spec.camera_link if robot.spec.camera_link is not None else HAND_LINK
    cached = c.getLinkState(robot.uid, link)
    current = c.getLinkState(robot.uid, link, computeForwardKinematics=True)  # refreshes the cache: last
    moved = np.array(current[4]) - np.array(cached[4])
    assert np.linalg.norm(moved) > 1e-4  # the cached transform is a sub-step behind
    if robot.spec.camera_link is not None:
        np.testing.assert_array_equal(position, np.array(cached[0]))
    else:  # the procedural Panda has no camera link: cached hand transform + CALVIN's camera offset
        offset_pos, offset_rpy = CAMERA_FROM_HAND
        expected, _ = c.multiplyTransforms(
            cached[4], cached[5], offset_pos, c.getQuaternionFromEuler(offset_rpy)
        )
        np.testing.assert_allclose(position, np.array(expected), atol=1e-12)
    assert rotation.shape == (3, 3)


def test_pybullet_link_state_default_is_the_cached_transform() -> None:
    """The premise: without computeForwardKinematics pybullet returns the stale (cached) transform."""
    client = pybullet.connect(pybullet.DIRECT)
    try:
        import pybullet_data

        pybullet.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client)
        uid = pybullet.loadURDF("franka_panda/panda.urdf", useFixedBase=True, physicsClientId=client)
        pybullet.setJointMotorControl2(uid, 0, pybullet.VELOCITY_CONTROL, targetVelocity=2.0, force=500,
                                       physicsClientId=client)  # fmt: skip
        for _ in range(10):
            pybullet.stepSimulation(physicsClientId=client)
        stale = pybullet.getLinkState(uid, 7, physicsClientId=client)[0]
        fresh = pybullet.getLinkState(uid, 7, computeForwardKinematics=True, physicsClientId=client)[0]
        assert not np.allclose(stale, fresh, atol=1e-6)
    finally:
        pybullet.disconnect(client)


@pytest.mark.calvin_assets
def test_calvin_scene_loads_its_blocks_where_a_fresh_calvin_env_does(calvin_assets_dir) -> None:
    """CALVIN samples the load poses from np_random(seed 0) in config order: surface, position, euler."""
    sim = CalvinSimulation("calvin_D", assets_dir=calvin_assets_dir, cameras=False)
    try:
        rng = np.random.default_rng(0)  # gymnasium's np_random(0)
        surfaces = sim.scene.source.surfaces
        for uid in sim.scene.block_uids.values():  # slot order = the scene config's order
            low, high = surfaces[str(rng.choice(list(surfaces)))]
            expected_position = rng.uniform(low, high)
            expected_euler = rng.uniform([0, 0, -np.pi], [0, 0, np.pi])
            position, orientation = sim.client.getBasePositionAndOrientation(uid)
            np.testing.assert_allclose(position, expected_position, atol=1e-9)
            np.testing.assert_allclose(
                orientation, sim.client.getQuaternionFromEuler(expected_euler.tolist()), atol=1e-9
            )
            assert np.all(np.array(position) >= np.array(low) - 1e-9)
    finally:
        sim.close()
