"""The open-loop diagnostic of the study: its error is that of the executed actions against the recorded ones
(padding past an episode's end left out), it runs on a trained checkpoint, and bad groups end in one line."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from helpers.robot_datasets import make_robot_dataset_in_subprocess
from helpers.study import study_module
from helpers.tiny_training import train_tiny

from lerobot_subgoalvla.contract.keys import ACTION_IS_PAD_KEY, ACTION_KEY, TASK_KEY
from lerobot_subgoalvla.datasets_conversion.add_traces import add_traces


@pytest.fixture
def open_loop_error(monkeypatch: pytest.MonkeyPatch):
    yield from study_module(monkeypatch, "open_loop_error")


class OffsetPolicy:
    """Predicts the recorded chunk moved by 0.3 along the first action dimension."""

    config = SimpleNamespace(n_action_steps=3, image_features={})

    def predict_action_chunk(self, batch: dict) -> torch.Tensor:
        chunk = batch[ACTION_KEY].clone()
        chunk[..., 0] += 0.3
        return chunk


def test_the_error_is_of_the_executed_steps_and_skips_padding(open_loop_error):
    actions = torch.zeros(2, 5, 2)
    pad = torch.zeros(2, 5, dtype=torch.bool)
    pad[1, 1:] = True  # the second frame is an episode's last: one real step
    items = [{ACTION_KEY: actions[i], ACTION_IS_PAD_KEY: pad[i]} for i in range(2)]

    def identity(x):
        return x

    chunk, first, per_dimension = open_loop_error.executed_errors(
        OffsetPolicy(), identity, identity, items, [0, 1], 4
    )
    assert chunk == pytest.approx([0.3, 0.3])
    assert first == pytest.approx([0.3, 0.3])
    assert open_loop_error.dimension_line(per_dimension, ["x", "grip"]) == "x 0.300 grip 0.000"


class ImageReadingPolicy:
    """Predicts the recorded chunk moved by its camera image's mean along the first action dimension."""

    config = SimpleNamespace(n_action_steps=1, image_features={"observation.image": None})

    def predict_action_chunk(self, batch: dict) -> torch.Tensor:
        chunk = batch[ACTION_KEY].clone()
        chunk[..., 0] += batch["observation.image"].mean(dim=(1, 2, 3)).unsqueeze(-1)
        return chunk


def test_images_from_another_episode_move_a_policy_that_reads_them(open_loop_error):
    items = [
        {
            ACTION_KEY: torch.zeros(2, 2),
            ACTION_IS_PAD_KEY: torch.zeros(2, dtype=torch.bool),
            "observation.image": torch.full((3, 4, 4), value),
            "observation.wrist": torch.full((3, 2, 2), value),  # a camera the policy does not read
        }
        for value in (0.0, 0.5)
    ]

    def identity(x):
        return x

    own, *_ = open_loop_error.executed_errors(ImageReadingPolicy(), identity, identity, items, [0, 1], 2)
    other, *_ = open_loop_error.executed_errors(
        ImageReadingPolicy(), identity, identity, items, [0, 1], 2, image_donors=[1, 0]
    )
    assert own == pytest.approx([0.0, 0.5])
    assert other == pytest.approx([0.5, 0.0])
    only_another_camera, *_ = open_loop_error.executed_errors(
        ImageReadingPolicy(), identity, identity, items, [0, 1], 2, [1, 0], None, ["observation.wrist"]
    )
    assert only_another_camera == pytest.approx([0.0, 0.5])  # the policy's camera kept its own image
    assert items[0]["observation.image"].max() == 0.0  # the dataset's own items are left as they were


class InstructionReadingPolicy:
    """Predicts the recorded chunk, moved by 0.4 along the first action dimension under instruction 'b'."""

    config = SimpleNamespace(n_action_steps=1, image_features={})

    def predict_action_chunk(self, batch: dict) -> torch.Tensor:
        chunk = batch[ACTION_KEY].clone()
        chunk[..., 0] += torch.tensor([0.4 * (task == "b") for task in batch[TASK_KEY]]).unsqueeze(-1)
        return chunk


def test_another_instruction_moves_a_policy_that_reads_it(open_loop_error):
    items = [
        {ACTION_KEY: torch.zeros(2, 2), ACTION_IS_PAD_KEY: torch.zeros(2, dtype=torch.bool), TASK_KEY: "a"}
        for _ in range(2)
    ]

    def identity(x):
        return x

    policy = InstructionReadingPolicy()
    own, *_ = open_loop_error.executed_errors(policy, identity, identity, items, [0, 1], 2)
    swapped, *_ = open_loop_error.executed_errors(
        policy, identity, identity, items, [0, 1], 2, instruction="b"
    )
    assert own == pytest.approx([0.0, 0.0]) and swapped == pytest.approx([0.4, 0.4])
    assert items[0][TASK_KEY] == "a"


class CountingDataset:
    """Items of a constant image, counting how often each index is decoded."""

    def __init__(self) -> None:
        self.decoded: list[int] = []

    def __getitem__(self, index: int) -> dict:
        self.decoded.append(index)
        return {
            ACTION_KEY: torch.zeros(2, 2),
            ACTION_IS_PAD_KEY: torch.zeros(2, dtype=torch.bool),
            "observation.image": torch.full((3, 4, 4), float(index)),
        }


def test_every_variant_of_a_group_decodes_each_frame_once(open_loop_error):
    dataset = CountingDataset()
    frames = open_loop_error.DecodedFrames(dataset)

    def identity(x):
        return x

    policy = ImageReadingPolicy()
    own, *_ = open_loop_error.executed_errors(policy, identity, identity, frames, [0, 1], 2)
    other, *_ = open_loop_error.executed_errors(
        policy, identity, identity, frames, [0, 1], 2, image_donors=[1, 0]
    )
    assert own == pytest.approx([0.0, 1.0]) and other == pytest.approx([1.0, 0.0])
    assert sorted(dataset.decoded) == [0, 1]


def test_the_other_episode_gives_the_same_step_or_its_last_frame(open_loop_error):
    spans = [
        {"dataset_from_index": 0, "dataset_to_index": 10},
        {"dataset_from_index": 10, "dataset_to_index": 14},
    ]
    dataset = SimpleNamespace(meta=SimpleNamespace(episodes=spans))
    assert open_loop_error.frame_indices(dataset, [0, 1], 3) == [0, 3, 6, 9, 10, 13]
    assert open_loop_error.other_episode_indices(dataset, [0, 1], 3) == [10, 13, 13, 13, 0, 3]


def test_a_malformed_group_ends_in_one_line(open_loop_error, caplog):
    with pytest.raises(SystemExit) as stop:
        open_loop_error.main(["--policy-path", "x", "--dataset-root", "y", "--group", "trained=5-2"])
    assert stop.value.code == 1
    assert "--group 'trained=5-2': write NAME=FIRST-LAST or NAME=A-B,C,..." in caplog.text


def test_a_group_may_list_scattered_episodes(open_loop_error):
    assert open_loop_error.parse_group("lift=3-5,9,12-13") == ("lift", [3, 4, 5, 9, 12, 13])
    assert open_loop_error.parse_group("one=7") == ("one", [7])
    with pytest.raises(ValueError, match="NAME=A-B,C"):
        open_loop_error.parse_group("bad=3,,5")


def test_a_trained_checkpoint_prints_one_row_per_group(open_loop_error, tmp_path: Path, capsys):
    make_robot_dataset_in_subprocess(tmp_path / "raw", {"observation.image": 24}, 2, 2, use_videos=False)
    dataset = add_traces("local/robot", tmp_path / "raw", tmp_path / "traces")
    checkpoint = train_tiny(dataset.root, "local/robot", tmp_path / "train")
    argv = ["--policy-path", str(checkpoint), "--dataset-root", str(dataset.root), "--repo-id", "local/robot"]
    assert open_loop_error.main([*argv, "--group", "first=0-0", "--group", "both=0-1", "--every", "6"]) == 0
    out = capsys.readouterr().out  # after a line LeRobot prints while loading
    rows = [line.split() for line in out[out.index("group ") :].splitlines()[1:]]
    assert [tuple(row[:4]) for row in rows] == [("first", "own", "1", "4"), ("both", "own", "2", "8")]
    assert all(float(value) >= 0 for row in rows for value in row[4:])
    assert open_loop_error.main([*argv, "--group", "both=0-1", "--images-from-other-episode"]) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out[out.index("group ") :].splitlines()[1:]]
    assert [tuple(row[:2]) for row in rows] == [("both", "own"), ("both", "other")]
    assert open_loop_error.main([*argv, "--group", "both=0-1", "--instruction", "open the drawer"]) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out[out.index("group ") :].splitlines()[1:]]
    assert [tuple(row[:2]) for row in rows] == [("both", "own"), ("both", "instr")]
    assert open_loop_error.main([*argv, "--group", "both=0-1", "--per-dimension"]) == 0
    out = capsys.readouterr().out
    lines = out[out.index("group ") :].splitlines()[1:]
    assert lines[1].split()[:2] == ["per", "dimension:"] and len(lines[1].split()) == 2 + 2 * 2
    with pytest.raises(SystemExit):  # a camera swap without the swap
        open_loop_error.main([*argv, "--group", "both=0-1", "--swap-camera=observation.image"])
    with pytest.raises(SystemExit):  # a camera the policy does not have
        open_loop_error.main(
            [*argv, "--group", "both=0-1", "--images-from-other-episode", "--swap-camera", "x"]
        )

    with pytest.raises(SystemExit):  # a group past the dataset's last episode
        open_loop_error.main([*argv, "--group", "late=1-2"])
