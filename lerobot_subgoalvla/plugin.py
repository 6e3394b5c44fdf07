"""Registration with LeRobot: importing this module registers everything the plugin adds.

- the policy type ``subgoalvla`` (``SubgoalVLAConfig``) and its LR scheduler ``subgoalvla_two_stage_cosine``;
- the processor steps ``subgoalvla_tokenizer_processor`` and ``subgoalvla_proprio_normalizer``, which a saved
  pipeline names and ``PolicyProcessorPipeline.from_pretrained`` looks up;
- the env type ``calvin`` (``CalvinEnvConfig``);
- a one-line notice instead of LeRobot's long torchcodec report on machines without FFmpeg's shared libraries
  (``decoder_probe``), and one ``error:`` line instead of a traceback when the data does not fit the policy
  (``config_error.DatasetContractError``, raised after LeRobot parsed its config).

LeRobot's ``register_third_party_plugins()`` imports it through the discovery shim
``lerobot_policy_subgoalvla`` (``lerobot-train``, ``lerobot-eval``, ...). Scripts of your own import it once:
``import lerobot_subgoalvla.plugin`` (or ask for a name: ``from lerobot_subgoalvla import SubgoalVLAPolicy``
imports it too).

Nothing here imports transformers or the model: LeRobot's factory imports ``modeling_subgoalvla`` (the
network, transformers) when a policy is built, and the tokenizer step loads the backbone's tokenizer when it
is first used.
"""

from lerobot_subgoalvla import decoder_probe
from lerobot_subgoalvla.config_error import install_one_line_excepthook
from lerobot_subgoalvla.envs.calvin.configs import CalvinEnvConfig
from lerobot_subgoalvla.policies.subgoalvla.configuration_subgoalvla import SubgoalVLAConfig
from lerobot_subgoalvla.policies.subgoalvla.processor_subgoalvla import (
    SubgoalVLATokenizerProcessorStep,
    make_subgoalvla_pre_post_processors,
)
from lerobot_subgoalvla.policies.subgoalvla.proprio_normalization import ProprioNormalizerProcessorStep

decoder_probe.install()
install_one_line_excepthook()

__all__ = [
    "CalvinEnvConfig",
    "ProprioNormalizerProcessorStep",
    "SubgoalVLAConfig",
    "SubgoalVLATokenizerProcessorStep",
    "make_subgoalvla_pre_post_processors",
]
