"""The study runs kept in the repository continue on any clone: no file of a kept policy names a path of the
machine that trained it (lerobot-train writes absolute paths; a kept run names its files from the repository
root, where the scripts run)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers.study import STUDY

KEPT_POLICY_FILES = sorted((STUDY / "runs").glob("*/pretrained_model/*.json"))


def _strings(value: object) -> Iterator[str]:
    if isinstance(value, str):
        yield value
    elif isinstance(value, dict):
        for item in value.values():
            yield from _strings(item)
    elif isinstance(value, list):
        for item in value:
            yield from _strings(item)


@pytest.mark.parametrize("path", KEPT_POLICY_FILES, ids=lambda p: str(p.relative_to(STUDY / "runs")))
def test_a_kept_policy_names_no_path_of_the_machine_that_trained_it(path: Path) -> None:
    absolute = [text for text in _strings(json.loads(path.read_text())) if text.startswith("/")]
    assert not absolute, f"{path}: name these from the repository root instead: {absolute}"


def test_the_repository_keeps_policies_to_check() -> None:
    assert KEPT_POLICY_FILES
