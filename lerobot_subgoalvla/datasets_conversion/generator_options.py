"""What determines the data ``subgoalvla-generate-calvin`` writes: its options, validated (one line naming the
flag), and the per-segment choices they imply (segment sizes, first tasks, next-task weights)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_subgoalvla.calvin_vocab import FIXTURE_TASKS, TASK_NAMES, check_task_name
from lerobot_subgoalvla.cli_errors import require_at_least
from lerobot_subgoalvla.envs.calvin.protocol import RENDERERS


@dataclass(frozen=True)
class GeneratorOptions:
    """Everything that determines the generated data (recorded in ``OUTPUT/.segments/options.json``)."""

    num_tasks: int
    seed: int
    scene: str = "procedural"
    assets_dir: str | None = None
    val_fraction: float = 0.1
    tasks_per_segment: int = 8
    max_steps_per_task: int = 360
    static_size: int = 200
    gripper_size: int = 84
    tasks: tuple[str, ...] = TASK_NAMES
    renderer: str = "tiny"
    #: Start segment i with the task at i in a seeded cycle over ``tasks`` (instead of a random one), so every
    #: task opens as many segments: with uniform choices among the *feasible* tasks, tasks feasible in few
    #: states (most block tasks) get a fraction of the demonstrations the fixtures get.
    balanced_starts: bool = False
    #: Start a window that follows a confirmed task where that task's oracle first fired, the state a CALVIN
    #: chain hands to its next subtask (fingers still at the fixture), not after the expert's retreat
    #: (``calvin_play`` module docstring; issue 25: without it no window starts in those states).
    windows_from_completion: bool = False
    #: Chance of a fixture task (``calvin_vocab.FIXTURE_TASKS``) relative to any other task when a segment's
    #: next task is drawn among the feasible ones; 1: uniform (the default data). Below 1 the block tasks,
    #: feasible in fewer states, get more of the segments' later attempts.
    fixture_weight: float = 1.0

    def __post_init__(self) -> None:
        if self.renderer not in RENDERERS:
            raise ValueError(f"--renderer={self.renderer!r} is not valid; use one of: {', '.join(RENDERERS)}")
        if not self.tasks:
            raise ValueError("--tasks needs at least one CALVIN task name")
        for task in self.tasks:
            check_task_name(task)
        positive = {"--num-tasks": self.num_tasks, "--tasks-per-segment": self.tasks_per_segment,
                    "--max-steps-per-task": self.max_steps_per_task, "--static-size": self.static_size,
                    "--gripper-size": self.gripper_size}  # fmt: skip
        require_at_least(1, positive)
        require_at_least(0, {"--seed": self.seed})  # numpy's SeedSequence takes non-negative entropy only
        if not self.fixture_weight > 0:
            raise ValueError(f"--fixture-weight must be > 0 (1: uniform), got {self.fixture_weight}")
        if not 0.0 <= self.val_fraction < 1.0:
            raise ValueError(f"--val-fraction must be in [0, 1), got {self.val_fraction}")
        if self.val_fraction > 0 and len(self.segment_tasks()) < 2:
            raise ValueError(
                f"--num-tasks {self.num_tasks} with --tasks-per-segment {self.tasks_per_segment} is one "
                f"segment, and --val-fraction {self.val_fraction} needs 2 (one per split); lower "
                "--tasks-per-segment, raise --num-tasks or pass --val-fraction 0"
            )

    @property
    def scene_name(self) -> str:
        """scene_info.npy name: ``calvin_A`` -> ``calvin_scene_A``; ``procedural`` stays."""
        return (
            self.scene.replace("calvin_", "calvin_scene_") if self.scene.startswith("calvin_") else self.scene
        )

    def segment_tasks(self) -> list[int]:
        """Task count of each segment (the last one takes the remainder)."""
        full, rest = divmod(self.num_tasks, self.tasks_per_segment)
        return [self.tasks_per_segment] * full + ([rest] if rest else [])

    def task_weights(self) -> dict[str, float] | None:
        """Relative chances of the next task among the feasible ones (``calvin_play.draw_next_task``)."""
        if self.fixture_weight == 1.0:
            return None  # uniform, drawn exactly as before the option existed
        return dict.fromkeys(FIXTURE_TASKS, self.fixture_weight)

    def first_task(self, segment: int) -> str | None:
        """The task segment ``segment`` starts with under ``balanced_starts``; None: a random one."""
        if not self.balanced_starts:
            return None
        order = np.random.default_rng(np.random.SeedSequence([self.seed, 2**31 - 2])).permutation(
            len(self.tasks)
        )
        return self.tasks[int(order[segment % len(self.tasks)])]

    def validation_segments(self) -> set[int]:
        """Segments of the validation split: a seeded random ``val_fraction`` of them (>= 1 if fraction >
        0)."""
        count = len(self.segment_tasks())
        num_val = min(count - 1, max(1, round(self.val_fraction * count))) if self.val_fraction > 0 else 0
        order = np.random.default_rng(np.random.SeedSequence([self.seed, 2**31 - 1])).permutation(count)
        return {int(i) for i in order[:num_val]}
