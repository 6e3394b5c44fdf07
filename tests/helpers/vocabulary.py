"""The tiny backbone's vocabulary for tests that build a policy without a dataset: CALVIN's words.

``lerobot-train`` fills ``--policy.backbone.vocabulary`` from the training dataset; a config built by hand
(unit tests, benchmarks) names its words itself.
"""

from __future__ import annotations

from lerobot_subgoalvla.calvin_vocab import EVAL_INSTRUCTIONS, TRAINING_ANNOTATIONS
from lerobot_subgoalvla.policies.subgoalvla.backbone import vocabulary_words
from lerobot_subgoalvla.policies.subgoalvla.config_components import BackboneConfig

#: every word of CALVIN's evaluation instructions and training annotations.
CALVIN_WORDS = list(
    vocabulary_words(
        [*EVAL_INSTRUCTIONS.values(), *(t for texts in TRAINING_ANNOTATIONS.values() for t in texts)]
    )
)


def calvin_backbone(**fields: object) -> BackboneConfig:
    """A ``BackboneConfig`` whose tiny tokenizer knows CALVIN's words; ``fields`` set the rest."""
    return BackboneConfig(vocabulary=list(CALVIN_WORDS), **fields)
