"""``lerobot-eval`` with SubgoalVLA's state history held static: at every step the policy sees the current
state repeated ``h`` times (the history every episode starts with) instead of the states it went through.

A probe, not a recipe: it asks whether a trained policy leans on extrapolating its own recent motion (the
"copycat" pattern of behaviour cloning with a state history) rather than reading the goal from its camera. If
the success rate rises when the history can no longer tell the policy how it was moving, the history is doing
harm at evaluation. Everything else is ``lerobot-eval`` unchanged, with its own flags.

Usage::

    python benchmarks/study/static_history_eval.py --policy.path=CKPT --env.type=metaworld \\
        --env.task=reach-v3 --eval.n_episodes=10 --eval.batch_size=2 --output_dir=OUT --seed=1000
"""

from __future__ import annotations

import sys

from lerobot_subgoalvla.policies.subgoalvla.state_history import StateHistoryBuffer


def static_push(push):
    """``StateHistoryBuffer.push`` that forgets the buffered states first, so the history it returns is the
    newest state repeated (what ``push`` returns after a reset)."""

    def push_static(self: StateHistoryBuffer, state):
        self.reset()
        return push(self, state)

    return push_static


def main() -> int:
    StateHistoryBuffer.push = static_push(StateHistoryBuffer.push)
    from lerobot.scripts.lerobot_eval import main as lerobot_eval

    return lerobot_eval()


if __name__ == "__main__":
    sys.exit(main())
