"""SubgoalVLA on any LeRobotDataset: the user's path from their own data to a checkpoint that acts.

Each case is a synthetic dataset of another robot (1 or 3 cameras, 2-, 7- or 14-dim state, image or video
frames, with or without wrapping angles) taken through ``subgoalvla-add-traces`` -> ``lerobot-train`` (a few
steps, tiny preset) -> the saved checkpoint loaded -> saved again -> reloaded, with identical actions from
``select_action``. The cases cover every value of every axis, not the full product (4 runs of lerobot-train).
Three cameras are written as images: LeRobot's AV1 encoder pool (one process per camera) died with a
floating-point exception in SVT-AV1 for three 64-80 px video cameras inside the test run on a loaded 2-core
machine, while the same call alone succeeded.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from helpers.robot_datasets import make_robot_dataset_in_subprocess
from helpers.tiny_training import train_tiny
from lerobot.policies import make_pre_post_processors

import lerobot_subgoalvla.plugin  # noqa: F401  (registers the policy type)
from lerobot_subgoalvla.contract.keys import TASK_KEY
from lerobot_subgoalvla.datasets_conversion.add_traces import add_traces
from lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla import SubgoalVLAPolicy

ALOHA = {
    "observation.images.top": 24,
    "observation.images.left_wrist": 16,
    "observation.images.right_wrist": 16,
}
CASES = {
    "pusht_like_1cam_2d_images": ({"observation.image": 24}, 2, 2, False, ()),
    "aloha_like_3cam_14d_images_angles": (ALOHA, 14, 14, False, (3, 4, 5)),
    "arm_1cam_7d_video_angle": ({"observation.images.front": 64}, 7, 7, True, (6,)),
    "arm_2cam_7d_video": ({"observation.images.front": 64, "observation.images.wrist": 64}, 7, 4, True, ()),
}


def _actions(checkpoint: Path, observation: dict) -> torch.Tensor:
    policy = SubgoalVLAPolicy.from_pretrained(checkpoint)
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    torch.manual_seed(0)
    return post(policy.select_action(pre(dict(observation))))


@pytest.mark.parametrize("case", list(CASES))
def test_a_users_dataset_trains_saves_reloads_and_acts_the_same(case: str, tmp_path: Path) -> None:
    cameras, state_dim, action_dim, videos, angles = CASES[case]
    make_robot_dataset_in_subprocess(tmp_path / "raw", cameras, state_dim, action_dim, use_videos=videos)
    home = tuple(0.0 for _ in angles)
    dataset = add_traces(
        "local/robot", tmp_path / "raw", tmp_path / "traces", angle_dims=angles, angle_home=home
    )
    checkpoint = train_tiny(dataset.root, "local/robot", tmp_path / "train")
    policy = SubgoalVLAPolicy.from_pretrained(checkpoint)
    assert policy.config.image_features_in_order == list(cameras)  # the dataset's order
    assert tuple(policy.config.state_angle_dims) == angles
    assert policy.config.backbone.vocabulary == ["block", "fold", "goal", "push", "the", "to", "towel"]
    policy.save_pretrained(tmp_path / "resaved")
    for name in ("policy_preprocessor.json", "policy_postprocessor.json"):
        (tmp_path / "resaved" / name).write_bytes((checkpoint / name).read_bytes())
    for path in checkpoint.glob("policy_*processor_step_*.safetensors"):
        (tmp_path / "resaved" / path.name).write_bytes(path.read_bytes())
    item = dataset[5]
    observation = {key: item[key] for key in (*cameras, "observation.state")}
    observation[TASK_KEY] = item[TASK_KEY]
    first, second = _actions(checkpoint, observation), _actions(tmp_path / "resaved", observation)
    assert first.shape == (1, action_dim) and torch.isfinite(first).all()
    torch.testing.assert_close(first, second, rtol=0, atol=0)
