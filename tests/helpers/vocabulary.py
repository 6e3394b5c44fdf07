"""The tiny backbone's vocabulary for tests that build a policy without a dataset: CALVIN's words.

``lerobot-train`` fills ``--policy.backbone.vocabulary`` from the training dataset; a config built by hand
(unit tests, benchmarks) names its words itself.
"""

from __future__ import annotations

from lerobot_subgoalvla.calvin_vocab import ALL_INSTRUCTIONS
from lerobot_subgoalvla.policies.subgoalvla.config_components import BackboneConfig
from lerobot_subgoalvla.policies.subgoalvla.tokenizer import vocabulary_words

#: every word of CALVIN's evaluation instructions and training annotations.
CALVIN_WORDS = list(vocabulary_words(ALL_INSTRUCTIONS))


def calvin_backbone(**fields: object) -> BackboneConfig:
    """A ``BackboneConfig`` whose tiny tokenizer knows CALVIN's words; ``fields`` set the rest."""
    return BackboneConfig(vocabulary=list(CALVIN_WORDS), **fields)
