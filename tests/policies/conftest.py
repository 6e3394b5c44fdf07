"""Fixtures for the SubgoalVLA policy tests: one tiny data-contract dataset per session, config/policy
factories.

Everything is tiny (32x32 static / 16x16 gripper images, the ``tiny`` preset), offline and on the CPU.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import torch
from helpers.lerobot_datasets import make_tiny_calvin_dataset
from helpers.vocabulary import calvin_backbone
from lerobot.datasets import LeRobotDataset
from lerobot.policies.factory import make_policy, make_pre_post_processors
from lerobot.utils.feature_utils import dataset_to_policy_features

from lerobot_subgoalvla.policies.subgoalvla.configuration_subgoalvla import SubgoalVLAConfig
from lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla import SubgoalVLAPolicy

TINY_REPO_ID = "local/tiny_calvin"
EPISODES, EPISODE_LEN = 3, 20
STATIC_SIZE, GRIPPER_SIZE = 32, 16
CHUNK_SIZE = 15
FPS = 30


@pytest.fixture(scope="session", autouse=True)
def _single_torch_thread() -> Iterator[None]:
    """Run the tiny models on one thread: their matrices are so small that OpenMP threads only contend for the
    shared cores (measured: a training step is ~100x slower with 2 threads on a loaded 2-core machine)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def tiny_dataset_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finalized tiny CALVIN-style dataset (3 episodes x 20 frames, 3 instructions)."""
    root = tmp_path_factory.mktemp("subgoalvla_policy") / "tiny_calvin"
    make_tiny_calvin_dataset(
        root,
        num_episodes=EPISODES,
        episode_len=EPISODE_LEN,
        static_size=STATIC_SIZE,
        gripper_size=GRIPPER_SIZE,
    )
    return root


@pytest.fixture(scope="session")
def tiny_dataset(tiny_dataset_root: Path) -> LeRobotDataset:
    """The tiny dataset opened for training: action chunks of ``CHUNK_SIZE`` (with padding masks)."""
    deltas = {"action": [i / FPS for i in range(CHUNK_SIZE)]}
    return LeRobotDataset(TINY_REPO_ID, root=tiny_dataset_root, delta_timestamps=deltas, video_backend="pyav")


@pytest.fixture
def make_config(tiny_dataset: LeRobotDataset) -> Callable[..., SubgoalVLAConfig]:
    """Factory: a tiny-preset config with the dataset's features; keyword arguments override fields."""

    def factory(**overrides: Any) -> SubgoalVLAConfig:
        features = dataset_to_policy_features(tiny_dataset.meta.features)
        overrides.setdefault("backbone", calvin_backbone())
        overrides.setdefault("preset", "tiny")  # the default is laptop
        return SubgoalVLAConfig(
            device="cpu",
            chunk_size=CHUNK_SIZE,
            input_features={k: v for k, v in features.items() if k != "action"},
            output_features={"action": features["action"]},
            **overrides,
        )

    return factory


@pytest.fixture
def make_policy_and_processors(
    tiny_dataset: LeRobotDataset,
) -> Callable[[SubgoalVLAConfig], tuple[SubgoalVLAPolicy, Any, Any]]:
    """Factory: (policy, preprocessor, postprocessor) built the way ``lerobot-train`` builds them."""

    def factory(config: SubgoalVLAConfig) -> tuple[SubgoalVLAPolicy, Any, Any]:
        policy = make_policy(config, ds_meta=tiny_dataset.meta)
        pre, post = make_pre_post_processors(config, dataset_stats=tiny_dataset.meta.stats)
        return policy, pre, post

    return factory


@pytest.fixture
def make_processors(tiny_dataset: LeRobotDataset) -> Callable[[SubgoalVLAConfig], tuple[Any, Any]]:
    """Factory: (preprocessor, postprocessor) from a config and the dataset statistics (no policy)."""

    def factory(config: SubgoalVLAConfig) -> tuple[Any, Any]:
        # lerobot-train builds the policy first, which adopts the dataset's window and angles into the config
        config.set_dataset_feature_metadata(tiny_dataset.meta.features)
        return make_pre_post_processors(config, dataset_stats=tiny_dataset.meta.stats)

    return factory


@pytest.fixture
def raw_batch(tiny_dataset: LeRobotDataset) -> dict[str, Any]:
    """A collated (not preprocessed) batch of 4 frames from different episodes."""
    items = [tiny_dataset[i] for i in (0, 7, 25, 47)]
    return torch.utils.data.default_collate(items)
