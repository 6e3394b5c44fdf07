"""CALVIN's vocabulary, shared by the env, the data path, the report and the processor.

One neutral module (docs/architecture.md, "The seams") so that no subpackage imports another for names.
Every fact here is from ``docs/calvin.md``: sections 1.4 / 1.5 (observation layouts), 2.3 (task ids and
names), 4.3 (evaluation instructions).
"""

from __future__ import annotations

import json
from pathlib import Path
from types import MappingProxyType

#: Frame rate of CALVIN's recordings and of its 30 Hz control loop (spec 1.6).
CALVIN_FPS = 30

#: ``robot_obs`` (15): spec section 1.4.
ROBOT_OBS_NAMES: tuple[str, ...] = (
    "tcp_pos_x", "tcp_pos_y", "tcp_pos_z",
    "tcp_euler_x", "tcp_euler_y", "tcp_euler_z",
    "gripper_opening_width",
    "arm_joint_1", "arm_joint_2", "arm_joint_3", "arm_joint_4", "arm_joint_5", "arm_joint_6", "arm_joint_7",
    "gripper_action",
)  # fmt: skip

#: Colours of the three movable blocks, in the slot order of scenes B and D (spec 1.5).
BLOCK_COLORS: tuple[str, ...] = ("red", "blue", "pink")


def _block_slot_names(slot: int) -> tuple[str, ...]:
    return tuple(f"block_slot{slot}_{axis}" for axis in ("x", "y", "z", "euler_x", "euler_y", "euler_z"))


#: ``scene_obs`` (24): spec section 1.5. Slots 0-2 hold the blocks in the scene's ``movable_objects`` order.
SCENE_OBS_NAMES: tuple[str, ...] = (
    "sliding_door", "drawer", "button", "switch", "lightbulb", "green_light",
    *_block_slot_names(0), *_block_slot_names(1), *_block_slot_names(2),
)  # fmt: skip

#: Relative action (7): position deltas, euler deltas (both normalised to [-1,
#: 1]), gripper (-1 close, +1 open).
ACTION_NAMES: tuple[str, ...] = ("d_x", "d_y", "d_z", "d_euler_x", "d_euler_y", "d_euler_z", "gripper")

#: The 34 tasks, ids = position (the order of ``new_playtable_tasks.yaml``, spec 2.3).
TASK_NAMES: tuple[str, ...] = (
    "rotate_red_block_right", "rotate_red_block_left",
    "rotate_blue_block_right", "rotate_blue_block_left",
    "rotate_pink_block_right", "rotate_pink_block_left",
    "push_red_block_right", "push_red_block_left",
    "push_blue_block_right", "push_blue_block_left",
    "push_pink_block_right", "push_pink_block_left",
    "move_slider_left", "move_slider_right",
    "open_drawer", "close_drawer",
    "lift_red_block_table", "lift_red_block_slider", "lift_red_block_drawer",
    "lift_blue_block_table", "lift_blue_block_slider", "lift_blue_block_drawer",
    "lift_pink_block_table", "lift_pink_block_slider", "lift_pink_block_drawer",
    "place_in_slider", "place_in_drawer",
    "stack_block", "unstack_block",
    "turn_on_lightbulb", "turn_off_lightbulb",
    "turn_on_led", "turn_off_led",
    "push_into_drawer",
)  # fmt: skip

#: The 8 tasks that move the desk's fixtures (drawer, sliding door, LED button, light-bulb switch): feasible
#: from almost every state, unlike most block tasks.
FIXTURE_TASKS: tuple[str, ...] = (
    "open_drawer", "close_drawer", "move_slider_left", "move_slider_right",
    "turn_on_led", "turn_off_led", "turn_on_lightbulb", "turn_off_lightbulb",
)  # fmt: skip


def _evaluation_instructions() -> dict[str, str]:
    instructions: dict[str, str] = {}
    for color in BLOCK_COLORS:
        instructions[f"rotate_{color}_block_right"] = f"take the {color} block and rotate it to the right"
        instructions[f"rotate_{color}_block_left"] = f"take the {color} block and rotate it to the left"
        instructions[f"push_{color}_block_right"] = f"go push the {color} block right"
        instructions[f"push_{color}_block_left"] = f"go push the {color} block left"
        instructions[f"lift_{color}_block_table"] = f"grasp and lift the {color} block"
        instructions[f"lift_{color}_block_slider"] = f"lift the {color} block from the sliding cabinet"
        instructions[f"lift_{color}_block_drawer"] = f"Take the {color} block from the drawer"
    instructions.update(
        move_slider_left="push the sliding door to the left side",
        move_slider_right="push the sliding door to the right side",
        open_drawer="pull the handle to open the drawer",
        close_drawer="push the handle to close the drawer",
        place_in_slider="store the grasped block in the sliding cabinet",
        place_in_drawer="store the grasped block in the drawer",
        push_into_drawer="slide the block that it falls into the drawer",
        stack_block="stack the grasped block",
        unstack_block="remove the stacked block",
        turn_on_lightbulb="use the switch to turn on the light bulb",
        turn_off_lightbulb="use the switch to turn off the light bulb",
        turn_on_led="press the button to turn on the led light",
        turn_off_led="press the button to turn off the led light",
    )
    return {task: instructions[task] for task in TASK_NAMES}


#: CALVIN's evaluation instruction per task (``new_playtable_validation.yaml``, spec 4.3). Unseen in training.
EVAL_INSTRUCTIONS: MappingProxyType[str, str] = MappingProxyType(_evaluation_instructions())


def check_task_name(task: str) -> str:
    """Return ``task`` if it is one of the 34 CALVIN tasks, else raise naming the valid ones."""
    if task not in EVAL_INSTRUCTIONS:
        raise ValueError(f"Unknown CALVIN task {task!r}; valid tasks: {', '.join(TASK_NAMES)}")
    return task


def _training_annotations() -> dict[str, tuple[str, ...]]:
    path = Path(__file__).with_name("calvin_training_annotations.json")
    annotations = json.loads(path.read_text())
    return {task: tuple(annotations[task]) for task in TASK_NAMES}


#: CALVIN's training instructions per task (spec 1.7): the 389 strings (7-20 per task) of mees/calvin
#: ``calvin_models/conf/annotations/new_playtable.yaml`` (``fa03f01``), in the
#: file's order within a task, kept as
#: data in ``calvin_training_annotations.json`` beside this module.
#: ``auto_lang_ann.npy``'s ``language.ann`` draws from these; ``EVAL_INSTRUCTIONS`` are not among them.
TRAINING_ANNOTATIONS: MappingProxyType[str, tuple[str, ...]] = MappingProxyType(_training_annotations())

#: every instruction CALVIN uses: the evaluation phrasing and all training annotations (what a policy
#: trained on a CALVIN dataset must read; tests and benchmarks build tiny vocabularies from it).
ALL_INSTRUCTIONS: tuple[str, ...] = (
    *EVAL_INSTRUCTIONS.values(),
    *(text for texts in TRAINING_ANNOTATIONS.values() for text in texts),
)
