"""The study's task-family groups for CALVIN play data: an instruction names its family, an instruction shared
by tasks of different families (or by none) is left out, and each family keeps its first episodes."""

from __future__ import annotations

import pytest
from helpers.study import study_module

from lerobot_subgoalvla.calvin_vocab import TRAINING_ANNOTATIONS


@pytest.fixture
def calvin_task_groups(monkeypatch: pytest.MonkeyPatch):
    yield from study_module(monkeypatch, "calvin_task_groups")


def test_episodes_go_to_the_family_their_instruction_names(calvin_task_groups):
    open_drawer = TRAINING_ANNOTATIONS["open_drawer"][0]
    rotate = TRAINING_ANNOTATIONS["rotate_red_block_left"][0]
    lift = TRAINING_ANNOTATIONS["lift_red_block_slider"][0]
    close_drawer = TRAINING_ANNOTATIONS["close_drawer"][0]  # no family
    pairs = [(5, rotate), (0, open_drawer), (3, lift), (1, close_drawer), (2, open_drawer), (4, "no text")]
    groups = calvin_task_groups.task_groups(pairs, per_group=1)
    assert groups == {"lift": [3], "rotate": [5], "drawer": [0]}
    assert calvin_task_groups.task_groups(pairs, per_group=5)["drawer"] == [0, 2]


def test_an_instruction_of_two_families_is_left_out(calvin_task_groups):
    tasks_of = {"do it": {"open_drawer", "rotate_red_block_left"}, "lift it": {"lift_red_block_table"}}
    assert calvin_task_groups.family_of("do it", tasks_of) is None
    assert calvin_task_groups.family_of("lift it", tasks_of) == "lift"
