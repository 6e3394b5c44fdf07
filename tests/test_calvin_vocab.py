"""The shared CALVIN vocabulary: layouts, task names, evaluation and training instructions (docs/calvin.md
1.4-1.7, 2.3, 4.3)."""

import pytest

from lerobot_subgoalvla.calvin_vocab import (
    EVAL_INSTRUCTIONS,
    ROBOT_OBS_NAMES,
    SCENE_OBS_NAMES,
    TASK_NAMES,
    TRAINING_ANNOTATIONS,
    check_task_name,
)


def test_layouts_and_task_ids():
    assert len(ROBOT_OBS_NAMES) == 15 and len(SCENE_OBS_NAMES) == 24
    assert len(TASK_NAMES) == len(set(TASK_NAMES)) == 34
    assert TASK_NAMES[14] == "open_drawer" and TASK_NAMES[33] == "push_into_drawer"  # ids of spec 2.3


def test_training_annotations_are_calvins_389_strings_unseen_at_evaluation():
    assert list(TRAINING_ANNOTATIONS) == list(TASK_NAMES)
    counts = [len(TRAINING_ANNOTATIONS[task]) for task in TASK_NAMES]
    assert sum(counts) == 389 and min(counts) >= 7 and max(counts) <= 20
    training = {text for texts in TRAINING_ANNOTATIONS.values() for text in texts}
    assert training.isdisjoint(EVAL_INSTRUCTIONS.values())
    assert EVAL_INSTRUCTIONS["lift_red_block_drawer"] == "Take the red block from the drawer"


def test_unknown_task_names_the_valid_ones():
    assert check_task_name("open_drawer") == "open_drawer"
    with pytest.raises(ValueError, match="valid tasks: rotate_red_block_right, .*push_into_drawer"):
        check_task_name("open_the_drawer")


def test_tiny_tokenizer_knows_every_training_and_evaluation_word():
    from helpers.vocabulary import CALVIN_WORDS

    from lerobot_subgoalvla.policies.subgoalvla.tokenizer import UNK_TOKEN, build_tiny_tokenizer

    tokenizer = build_tiny_tokenizer(CALVIN_WORDS)
    unk = tokenizer.convert_tokens_to_ids(UNK_TOKEN)
    texts = [*EVAL_INSTRUCTIONS.values(), *(t for texts in TRAINING_ANNOTATIONS.values() for t in texts)]
    unknown = [text for text in texts if unk in tokenizer(text, add_special_tokens=False)["input_ids"]]
    assert unknown == []
    led, bulb = (
        tokenizer(TRAINING_ANNOTATIONS[task][0])["input_ids"] for task in ("turn_on_led", "turn_on_lightbulb")
    )
    assert led != bulb
