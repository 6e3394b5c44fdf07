"""Shared fixtures: offline mode, deterministic seeds, the optional CALVIN asset directory."""

from __future__ import annotations

import os
import random
from pathlib import Path

import numpy as np
import pytest
import torch

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
os.environ.setdefault("MPLBACKEND", "Agg")

#: Where CALVIN's real scene files live on the developers' machines (never copied into the project).
DEFAULT_CALVIN_ASSETS = Path(__file__).resolve().parents[2] / "shared" / "calvin_env_assets"


def calvin_assets_path() -> Path | None:
    """The calvin_env asset directory from ``$CALVIN_ENV_ASSETS`` or the shared default, if it exists."""
    path = Path(os.environ.get("CALVIN_ENV_ASSETS", DEFAULT_CALVIN_ASSETS))
    return path if (path / "data").is_dir() else None


@pytest.fixture
def calvin_assets_dir() -> Path:
    """CALVIN's calvin_env directory (with ``data/`` and ``conf/``); skips the test when it is absent."""
    path = calvin_assets_path()
    if path is None:
        pytest.skip("CALVIN assets not found: set CALVIN_ENV_ASSETS to a clone of calvin_env")
    return path


@pytest.fixture(autouse=True)
def _seed_everything() -> None:
    random.seed(0)
    np.random.seed(0)
    torch.manual_seed(0)
