"""The block probe of the CALVIN study: the block an instruction names, the approach frames, the pose targets,
and a cross-validated ridge that finds a linear signal, finds none in noise, and scores angles modulo half a
turn."""

from __future__ import annotations

import math

import pytest
import torch
from helpers.study import study_module

from lerobot_subgoalvla.calvin_vocab import TRAINING_ANNOTATIONS


@pytest.fixture
def probe(monkeypatch: pytest.MonkeyPatch):
    yield from study_module(monkeypatch, "calvin_block_probe")


def test_an_instruction_names_its_block_or_none(probe):
    assert probe.block_of(TRAINING_ANNOTATIONS["lift_red_block_table"][0]) == "red"
    assert probe.block_of(TRAINING_ANNOTATIONS["rotate_pink_block_left"][0]) == "pink"
    assert probe.block_of(TRAINING_ANNOTATIONS["open_drawer"][0]) is None
    assert probe.block_of("no such instruction") is None


def test_the_approach_ends_at_the_first_closing_command(probe):
    states = torch.zeros(6, 15)
    states[:, probe.GRIPPER_COMMAND] = torch.tensor([1.0, 1, 1, -1, 1, -1])
    assert probe.approach_frames(states) == 3
    states[:, probe.GRIPPER_COMMAND] = 1.0
    assert probe.approach_frames(states) == 6


def test_the_targets_are_the_named_blocks_pose(probe):
    environment, states = torch.zeros(2, 24), torch.zeros(2, 15)
    environment[:, 12:14] = torch.tensor([[0.1, -0.2], [0.3, 0.0]])  # blue block's x, y
    environment[:, 17] = torch.tensor([0.25, math.pi / 2 + 0.25])  # blue block's yaw: the same block view
    environment[:, 11] = 1.0  # red block's yaw: must not enter
    states[:, probe.TCP_YAW] = 0.25
    targets = probe.block_targets(environment, states, "blue")
    assert torch.allclose(targets["xy"], environment[:, 12:14].double())
    assert torch.allclose(
        targets["yaw"][0], torch.tensor([math.cos(0.5), math.sin(0.5)], dtype=torch.float64)
    )
    assert torch.allclose(targets["yaw"][1], -targets["yaw"][0])  # a quarter turn is half a turn of 2a
    assert torch.allclose(targets["yaw_grip"][0], torch.tensor([1.0, 0.0], dtype=torch.float64))


def test_the_ridge_finds_a_linear_signal_and_none_in_noise(probe):
    generator = torch.Generator().manual_seed(0)
    features = torch.randn(400, 100, generator=generator, dtype=torch.float64)
    folds = torch.arange(400) % 5
    signal = features[:, :3] @ torch.tensor([[1.0], [-2.0], [0.5]], dtype=torch.float64)
    noise = torch.randn(400, 1, generator=generator, dtype=torch.float64)
    assert probe.r_squared(probe.best_held_out(features, signal, folds), signal) > 0.9
    assert probe.r_squared(probe.best_held_out(features, noise, folds), noise) < 0.1
    constant = torch.zeros(400, 1, dtype=torch.float64)
    assert probe.r_squared(probe.best_held_out(constant, signal, folds), signal) == pytest.approx(0, abs=0.05)


def test_angle_errors_are_taken_modulo_half_a_turn(probe):
    def pair(angles: list[float]) -> torch.Tensor:
        twice = 2 * torch.tensor(angles, dtype=torch.float64)
        return torch.stack([torch.cos(twice), torch.sin(twice)], dim=1)

    degrees = math.radians
    assert probe.median_angle_error_degrees(pair([0.3]), pair([0.3])) == pytest.approx(0, abs=1e-6)
    assert probe.median_angle_error_degrees(pair([0.0]), pair([degrees(90)])) == pytest.approx(90)
    assert probe.median_angle_error_degrees(pair([degrees(89)]), pair([degrees(-89)])) == pytest.approx(2)
    assert probe.median_angle_error_degrees(3 * pair([0.4]), pair([0.4])) == pytest.approx(0, abs=1e-6)
