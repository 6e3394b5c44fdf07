"""subgoalvla-render-traces: a saved tiny checkpoint rolled out in CalvinEnv, its traces drawn as ghost
robots."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from helpers.lerobot_datasets import make_tiny_calvin_dataset
from helpers.vocabulary import calvin_backbone
from lerobot.policies.factory import make_policy, make_pre_post_processors
from lerobot.utils.feature_utils import dataset_to_policy_features
from PIL import Image

from lerobot_subgoalvla.envs.calvin.env import CalvinEnv
from lerobot_subgoalvla.policies.subgoalvla.configuration_subgoalvla import SubgoalVLAConfig
from lerobot_subgoalvla.visualization import render_traces

STATIC, GRIPPER = 64, 32
N_ACTION_STEPS, STEPS = 3, 6  # two chunks planned


def _config(dataset: Any, **overrides: Any) -> SubgoalVLAConfig:
    features = dataset_to_policy_features(dataset.meta.features)
    overrides.setdefault("preset", "tiny")  # the default is laptop
    return SubgoalVLAConfig(
        device="cpu",
        backbone=calvin_backbone(),
        chunk_size=15,
        n_action_steps=N_ACTION_STEPS,
        input_features={k: v for k, v in features.items() if k != "action"},
        output_features={"action": features["action"]},
        **overrides,
    )


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory: pytest.TempPathFactory) -> Any:
    root = tmp_path_factory.mktemp("traces") / "tiny_calvin"
    return make_tiny_calvin_dataset(
        root, num_episodes=2, episode_len=12, static_size=STATIC, gripper_size=GRIPPER
    )


@pytest.fixture(scope="module")
def checkpoint(tiny_dataset: Any, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A saved tiny SubgoalVLA checkpoint (config, weights, processors with the dataset's statistics)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny matrices: extra threads only contend for the shared cores
    cfg = _config(tiny_dataset)
    policy = make_policy(cfg, ds_meta=tiny_dataset.meta)
    pre, post = make_pre_post_processors(cfg, dataset_stats=tiny_dataset.meta.stats)
    path = tmp_path_factory.mktemp("traces") / "pretrained_model"
    policy.save_pretrained(path)
    pre.save_pretrained(path)
    post.save_pretrained(path)
    yield path
    torch.set_num_threads(threads)


@pytest.fixture
def env() -> Iterator[CalvinEnv]:
    env = CalvinEnv("open_drawer", static_size=STATIC, gripper_size=GRIPPER, episode_length=50)
    yield env
    env.close()


def test_rollout_draws_each_planned_trace_over_its_observation(checkpoint, env, monkeypatch) -> None:
    policy, pre, post = render_traces.load_policy(checkpoint)
    drawn: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (trace, plain frame, overlay)
    render = render_traces.render_trace

    def recording(sim, trace, frame):
        overlay = render(sim, trace, frame)
        drawn.append((trace, frame.copy(), overlay))
        return overlay

    monkeypatch.setattr(render_traces, "render_trace", recording)
    frames = render_traces.rollout_with_traces(policy, pre, post, env, num_steps=STEPS, seed=0)

    assert len(frames) == STEPS // N_ACTION_STEPS  # one overlay per planned chunk
    assert all(f.shape == (STATIC, STATIC, 3) and f.dtype == np.uint8 for f in frames)
    assert any(not np.array_equal(plain, overlay) for _, plain, overlay in drawn)  # ghosts were drawn
    trace = policy.last_subgoal_trace
    assert trace is not None and trace.shape == (1, policy.config.subgoal_trace_len, 15)
    # the drawn rows are the last planned trace, un-normalised: back in robot_obs units
    expected = render_traces.unnormalize_state(pre, trace[0])
    np.testing.assert_allclose(drawn[-1][0], expected.numpy(), rtol=1e-6)
    policy.reset()
    assert policy.last_subgoal_trace is None


def test_unnormalize_state_inverts_the_preprocessor(checkpoint, tiny_dataset) -> None:
    _, pre, _ = render_traces.load_policy(checkpoint)  # statistics read back from disk
    frame = tiny_dataset[5]
    state = frame["observation.state"] + 0.3  # a known state, not one of the statistics' own points
    state[3] = math.pi - 0.1  # a roll near the wrap comes back as itself
    observation = {k: frame[k] for k in ("observation.images.static", "observation.images.gripper")}
    normalised = pre({**observation, "observation.state": state, "task": frame["task"]})["observation.state"]
    assert not torch.allclose(normalised[0], state)  # it was normalised
    torch.testing.assert_close(render_traces.unnormalize_state(pre, normalised[0]), state)


def test_unnormalize_state_needs_the_proprio_step(checkpoint) -> None:
    _, pre, _ = render_traces.load_policy(checkpoint)
    pre.steps = [step for step in pre.steps if type(step).__name__ != "ProprioNormalizerProcessorStep"]
    with pytest.raises(ValueError, match="0 subgoalvla_proprio_normalizer steps"):
        render_traces.unnormalize_state(pre, torch.zeros(8, 15))


def test_cli_writes_a_png_strip(checkpoint, tmp_path: Path) -> None:
    output = tmp_path / "strip.png"
    argv = [
        "--policy-path",
        str(checkpoint),
        "--task",
        "open_drawer",
        "--steps",
        "4",
        "--output",
        str(output),
    ]
    assert render_traces.main(argv) == 0
    strip = np.asarray(Image.open(output))
    assert strip.shape == (STATIC, 2 * STATIC, 3)  # chunks planned at steps 0 and 3


def test_cli_bad_path_is_one_line_and_nonzero(tmp_path: Path, caplog) -> None:
    argv = [
        "--policy-path",
        str(tmp_path / "nope"),
        "--task",
        "open_drawer",
        "--output",
        str(tmp_path / "a.mp4"),
    ]
    with pytest.raises(SystemExit) as exit_info:
        render_traces.main(argv)
    assert exit_info.value.code == 1
    assert "no config.json" in caplog.text and "pretrained_model" in caplog.text
    assert not (tmp_path / "a.mp4").exists()


def test_cli_refuses_a_checkpoint_of_another_policy_type(tmp_path: Path, caplog) -> None:
    import json

    checkpoint = tmp_path / "act_checkpoint"
    checkpoint.mkdir()
    from lerobot.policies.act.configuration_act import ACTConfig

    ACTConfig().save_pretrained(checkpoint)  # writes config.json with "type": "act"
    assert json.loads((checkpoint / "config.json").read_text())["type"] == "act"
    argv = ["--policy-path", str(checkpoint), "--task", "open_drawer", "--output", str(tmp_path / "a.png")]
    with pytest.raises(SystemExit) as exit_info:
        render_traces.main(argv)
    assert exit_info.value.code == 1
    assert "a 'act' checkpoint; only SubgoalVLA predicts subgoal traces" in caplog.text
    assert not (tmp_path / "a.png").exists()


@pytest.mark.parametrize("module", ["render_traces", "dataset_traces"])
def test_usage_errors_are_one_line_and_exit_1(module: str, caplog) -> None:
    """A missing flag is one log line and exit 1, as in every subgoalvla-* command (not argparse's usage)."""
    import importlib

    command = importlib.import_module(f"lerobot_subgoalvla.visualization.{module}")
    with pytest.raises(SystemExit) as exit_info:
        command.main([])
    assert exit_info.value.code == 1
    assert "the following arguments are required" in caplog.text and "usage:" not in caplog.text
