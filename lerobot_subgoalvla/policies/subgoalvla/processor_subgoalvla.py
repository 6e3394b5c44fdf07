"""Pre/post-processing pipelines of the SubgoalVLA policy (LeRobot 0.6 processor API).

Pre-processor (``policy_preprocessor``)::

    rename_observations_processor -> to_batch_processor -> subgoalvla_tokenizer_processor -> device_processor
    -> subgoalvla_proprio_normalizer -> normalizer_processor

Post-processor (``policy_postprocessor``): ``unnormalizer_processor -> device_processor (cpu)``.

Proprioception (``observation.state`` and its sequences ``observation.state_history`` /
``observation.subgoal_trace``) is normalised by our own step, with the state's statistics and the wrapping TCP
angles as continuous offsets (``proprio_normalization.py``); LeRobot's ``normalizer_processor`` handles the
action and leaves ``STATE`` features alone (the config maps ``STATE`` to ``IDENTITY``).

Images are left in [0, 1] (``VISUAL: IDENTITY``); the model resizes and normalises them for its vision tower.
The instruction (``task``) is tokenised here with the backbone's tokenizer, LLaVA style (image placeholders
first); the step stores only the backbone name / tiny dimensions, so a saved pipeline rebuilds it offline for
the tiny model.

Dimension legend (the package's, ``__init__.py``): ``B`` batch, ``p`` proprio dim, ``h`` history steps,
``M`` trace steps, ``S`` VLM tokens.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from typing import Any

import torch
from lerobot.configs import FeatureType, PipelineFeatureType, PolicyFeature
from lerobot.lerobot_types import RobotObservation, TransitionKey
from lerobot.processor import (
    ObservationProcessorStep,
    PolicyAction,
    PolicyProcessorPipeline,
    ProcessorStepRegistry,
    make_default_policy_processor_steps,
    make_policy_processor_pipelines,
)
from lerobot.utils.constants import OBS_LANGUAGE_ATTENTION_MASK, OBS_LANGUAGE_TOKENS

from lerobot_subgoalvla.contract.keys import STATE_KEY, TASK_KEY
from lerobot_subgoalvla.policies.subgoalvla.config_components import TinyLlavaDims
from lerobot_subgoalvla.policies.subgoalvla.configuration_subgoalvla import SubgoalVLAConfig
from lerobot_subgoalvla.policies.subgoalvla.proprio_normalization import ProprioNormalizerProcessorStep

logger = logging.getLogger(__name__)


@ProcessorStepRegistry.register(name="subgoalvla_tokenizer_processor")
@dataclass
class SubgoalVLATokenizerProcessorStep(ObservationProcessorStep):
    """Tokenise the instruction(s) in ``complementary_data["task"]`` for the VLM (LLaVA protocol).

    Adds ``observation.language.tokens`` (B, S) int64 (image placeholders + instruction + padding) and
    ``observation.language.attention_mask`` (B, S) bool.

    Args:
        name_or_path: the backbone checkpoint (its tokenizer and image-token facts); None = the tiny backbone.
        max_length: instruction tokens kept (``BackboneConfig.max_instruction_tokens``).
        tiny_dims: ``TinyLlavaDims`` fields of the tiny backbone (None for a pretrained one); they fix the
            number of image placeholders and the vocabulary (an instruction with words outside it logs one
            warning naming them: they become ``<unk>``).
        task_key: complementary-data key holding the instruction(s).
        images_per_sample: images the vision tower encodes per sample, each with its own run of placeholders
            (``SubgoalVLAConfig.images_per_sample``; 1 for the paper's side-by-side cameras).
    """

    name_or_path: str | None = None
    max_length: int = 32
    tiny_dims: dict[str, Any] | None = None
    task_key: str = TASK_KEY
    images_per_sample: int = 1
    _tokenizer: Any = field(default=None, init=False, repr=False)
    _warned: set[str] = field(default_factory=set, init=False, repr=False)  # instructions already reported
    _spec: Any = field(default=None, init=False, repr=False)  # backbone.VLMInputSpec
    _tokenize: Any = field(default=None, init=False, repr=False)  # backbone.tokenize_instructions

    def __post_init__(self) -> None:
        if (self.name_or_path is None) == (self.tiny_dims is None):
            raise ValueError("subgoalvla_tokenizer_processor needs exactly one of name_or_path / tiny_dims")
        # Imported here, not at module level: registering this step (lerobot_subgoalvla.plugin) must not load
        # transformers; building it does.
        from lerobot_subgoalvla.policies.subgoalvla.backbone import VLMInputSpec, tokenize_instructions
        from lerobot_subgoalvla.policies.subgoalvla.tokenizer import load_tokenizer

        self._tokenize = tokenize_instructions

        tiny = None
        if self.tiny_dims is not None:
            if "vocabulary" not in self.tiny_dims:
                raise ValueError(
                    "this SubgoalVLA checkpoint was saved before tiny vocabularies were stored with it "
                    "(lerobot-subgoalvla < 0.2); train it again with the current version"
                )
            tiny = TinyLlavaDims(**{**self.tiny_dims, "vocabulary": tuple(self.tiny_dims["vocabulary"])})
        self._tokenizer = load_tokenizer(self.name_or_path, tiny)
        self._spec = VLMInputSpec.load(self.name_or_path, tiny)

    @property
    def sequence_length(self) -> int:
        """S, the length of every tokenised instruction (BOS + image placeholders + max_length)."""
        bos = int(self._tokenizer.bos_token_id is not None)
        return bos + self._spec.num_image_tokens * self.images_per_sample + self.max_length

    def _instructions(self) -> list[str]:
        complementary = self.transition.get(TransitionKey.COMPLEMENTARY_DATA) or {}
        task = complementary.get(self.task_key)
        if isinstance(task, str):
            return [task]
        if isinstance(task, (list, tuple)) and task and all(isinstance(t, str) for t in task):
            return list(task)
        raise ValueError(
            f"SubgoalVLA needs the instruction in batch[{self.task_key!r}] (str or list[str]), got {task!r}"
        )

    def _warn_on_unknown_words(self, instructions: list[str]) -> None:
        """Log once per instruction the words a tiny vocabulary lacks (they become ``<unk>``)."""
        from lerobot_subgoalvla.policies.subgoalvla.tokenizer import unknown_words

        for text in set(instructions) - self._warned:
            self._warned.add(text)
            unknown = unknown_words([text], self.tiny_dims["vocabulary"])
            if unknown:
                logger.warning(
                    "instruction %r has words the policy never saw in training: %s (they read as <unk>)",
                    text,
                    unknown,
                )

    def observation(self, observation: RobotObservation) -> RobotObservation:
        instructions = self._instructions()
        if self.tiny_dims is not None:
            self._warn_on_unknown_words(instructions)
        input_ids, attention_mask = self._tokenize(
            self._tokenizer, instructions, self.max_length, self._spec, self.images_per_sample
        )
        device = next((v.device for v in observation.values() if isinstance(v, torch.Tensor)), None)
        observation = dict(observation)
        observation[OBS_LANGUAGE_TOKENS] = input_ids.to(device)  # (B, S)
        observation[OBS_LANGUAGE_ATTENTION_MASK] = attention_mask.to(
            device=device, dtype=torch.bool
        )  # (B, S)
        return observation

    def get_config(self) -> dict[str, Any]:
        return {
            "name_or_path": self.name_or_path,
            "max_length": self.max_length,
            "tiny_dims": self.tiny_dims,
            "task_key": self.task_key,
            "images_per_sample": self.images_per_sample,
        }

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        for key in (OBS_LANGUAGE_TOKENS, OBS_LANGUAGE_ATTENTION_MASK):
            features[PipelineFeatureType.OBSERVATION][key] = PolicyFeature(
                type=FeatureType.LANGUAGE, shape=(self.sequence_length,)
            )
        return features


def _tiny_dims_dict(config: SubgoalVLAConfig) -> dict[str, Any] | None:
    dims = config.backbone.tiny_dims()
    return None if dims is None else dataclasses.asdict(dims)


def make_subgoalvla_pre_post_processors(
    config: SubgoalVLAConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
    dataset_meta: Any | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    """Build SubgoalVLA's ``policy_preprocessor`` / ``policy_postprocessor`` (module docstring).

    Args:
        config: the policy config (features, normalisation mapping, backbone).
        dataset_stats: the dataset's statistics; ``observation.state``'s normalise state, history and trace
            (``ProprioNormalizerProcessorStep``), the history/trace columns' own statistics are never used.
        dataset_meta: the training dataset's metadata, when LeRobot passes it: its features are checked
            against the data contract (one line naming the missing feature and the command that adds it).

    Returns:
        (preprocessor, postprocessor).
    """
    if dataset_meta is not None:
        config.set_dataset_feature_metadata(dataset_meta.features)
    steps = make_default_policy_processor_steps(config, dataset_stats)
    tokenizer = SubgoalVLATokenizerProcessorStep(
        name_or_path=config.backbone.name_or_path,
        max_length=config.backbone.max_instruction_tokens,
        tiny_dims=_tiny_dims_dict(config),
        images_per_sample=config.images_per_sample,
    )
    return make_policy_processor_pipelines(
        input_steps=[
            steps.rename_observations,
            steps.add_batch_dim,
            tokenizer,
            steps.to_device,
            ProprioNormalizerProcessorStep.from_stats(
                (dataset_stats or {}).get(STATE_KEY),
                config.state_angle_dims or (),
                config.state_angle_home or (),
                config.state_angle_scale,
            ),
            steps.normalize,
        ],
        output_steps=[steps.unnormalize, steps.to_cpu],
    )
