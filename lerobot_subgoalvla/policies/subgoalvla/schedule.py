"""The learning-rate schedule of SubgoalVLA's two training stages (paper section 4.3, appendix C).

Appendix C trains each stage with a linear warmup (5 % of its steps) and a cosine decay to 3e-6. When one
``lerobot-train`` run switches from stage I to stage II at ``stage2_start_step``, a single cosine over the
whole run would start stage II far below the peak (27 % of it for a switch at 60 %), so stage II would barely
train.
This schedule restarts instead: each stage gets its own warmup + cosine over its own steps. Without a switch
it is the plain warmup + cosine of appendix C. It is a LambdaLR, so every parameter group keeps its own peak
rate (table 8) and the factor applies to all groups alike; ``--resume=true`` continues at the saved step.

Registered with LeRobot as the scheduler type ``subgoalvla_two_stage_cosine``; ``SubgoalVLAConfig`` returns it
as its scheduler preset.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lerobot.optim import LRSchedulerConfig
from torch.optim import Optimizer
from torch.optim.lr_scheduler import LambdaLR


def warmup_cosine_factor(step: int, length: int, warmup_ratio: float, final_ratio: float) -> float:
    """Learning-rate factor at ``step`` of a phase of ``length`` steps: linear warmup, then cosine to
    ``final_ratio``."""
    warmup = max(1, int(warmup_ratio * length))
    if step < warmup:
        return (step + 1) / warmup
    progress = min(1.0, (step - warmup) / max(1, length - warmup))
    return final_ratio + (1.0 - final_ratio) * 0.5 * (1.0 + math.cos(math.pi * progress))


@LRSchedulerConfig.register_subclass("subgoalvla_two_stage_cosine")
@dataclass
class TwoStageCosineSchedulerConfig(LRSchedulerConfig):
    """Warmup + cosine per training stage, restarted at the stage I -> II switch (module docstring).

    Each field's help is the comment above it: ``--help`` shows it.
    """

    # unused by this schedule (LeRobot's base field); the warmup is `warmup_ratio` of each stage.
    num_warmup_steps: int | None = None
    # fraction of each stage spent in linear warmup.
    warmup_ratio: float = 0.05
    # learning rate at the end of each stage as a fraction of the group's peak.
    final_ratio: float = 0.03
    # optimizer step of the stage switch (None: one stage over the whole run).
    stage2_start_step: int | None = None

    def phases(self, num_training_steps: int) -> list[tuple[int, int]]:
        """(first step, length) of each stage within ``num_training_steps``."""
        switch = self.stage2_start_step
        if switch is None or not 0 < switch < num_training_steps:
            return [(0, num_training_steps)]
        return [(0, switch), (switch, num_training_steps - switch)]

    def build(self, optimizer: Optimizer, num_training_steps: int) -> LambdaLR:
        phases = self.phases(num_training_steps)

        def factor(step: int) -> float:
            start, length = next((p for p in reversed(phases) if step >= p[0]), phases[0])
            return warmup_cosine_factor(step - start, length, self.warmup_ratio, self.final_ratio)

        return LambdaLR(optimizer, factor)
