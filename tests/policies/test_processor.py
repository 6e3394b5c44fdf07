"""SubgoalVLA processors: LeRobot's pipeline contract, tokenisation and state-consistent normalisation."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
import torch
from lerobot.datasets import LeRobotDataset
from lerobot.policies.factory import make_pre_post_processors
from lerobot.processor import ProcessorStepRegistry

from lerobot_subgoalvla.policies.subgoalvla.processor_subgoalvla import SubgoalVLATokenizerProcessorStep

HISTORY, TRACE, STATE = "observation.state_history", "observation.subgoal_trace", "observation.state"


def _state_stats(dataset: LeRobotDataset) -> tuple[torch.Tensor, torch.Tensor]:
    stats = dataset.meta.stats[STATE]
    return torch.as_tensor(stats["mean"]).float(), torch.as_tensor(stats["std"]).float()


def _registry_names(pipeline: Any) -> list[str]:
    return [getattr(step, "_registry_name", type(step).__name__) for step in pipeline.steps]


def test_pipelines_follow_lerobots_naming_contract(make_config, make_processors) -> None:
    pre, post = make_processors(make_config())
    assert pre.name == "policy_preprocessor" and post.name == "policy_postprocessor"
    names = _registry_names(pre)
    for required in ("rename_observations_processor", "device_processor", "normalizer_processor"):
        assert required in names  # lerobot-eval / fine-tuning override these by name
    assert "unnormalizer_processor" in _registry_names(post)
    assert ProcessorStepRegistry.get("subgoalvla_tokenizer_processor") is SubgoalVLATokenizerProcessorStep


def _expected_proprio(raw: torch.Tensor, mean: torch.Tensor, std: torch.Tensor) -> torch.Tensor:
    """Linear dims z-scored with the state statistics; TCP angles (3, 4, 5) as wrap(angle - (pi, 0, 0))."""
    expected = (raw - mean) / (std + 1e-8)
    home = torch.tensor([math.pi, 0.0, 0.0])
    expected[..., 3:6] = torch.remainder(raw[..., 3:6] - home + math.pi, 2 * math.pi) - math.pi
    return expected


def test_history_and_trace_use_the_state_statistics(make_config, make_processors, raw_batch, tiny_dataset):
    pre, _ = make_processors(make_config())
    out = pre(dict(raw_batch))
    mean, std = _state_stats(tiny_dataset)
    for key in (STATE, HISTORY, TRACE):
        torch.testing.assert_close(out[key], _expected_proprio(raw_batch[key], mean, std))
    # LeRobot's own pooled statistics of the history column differ, so this is a real choice, not a
    # coincidence
    own = tiny_dataset.meta.stats[HISTORY]
    assert not torch.allclose(torch.as_tensor(own["mean"]).float(), mean)
    assert (
        out["observation.images.static"].min() >= 0 and out["observation.images.static"].max() <= 1
    )  # [0, 1]


def test_wrapping_roll_stays_continuous(make_config, make_processors, raw_batch) -> None:
    """A roll of +pi - 0.01 and -pi + 0.01 are 0.02 rad apart: so are their normalised values."""
    pre, _ = make_processors(make_config())
    batch = dict(raw_batch)
    state = batch[STATE].clone()
    state[0, 3], state[1, 3] = math.pi - 0.01, -math.pi + 0.01
    out = pre({**batch, STATE: state})[STATE]
    assert abs(float(out[0, 3] - out[1, 3])) == pytest.approx(0.02, abs=1e-5)


def test_instruction_tokens_follow_the_llava_protocol(make_config, make_processors, raw_batch) -> None:
    cfg = make_config()
    pre, _ = make_processors(cfg)
    out = pre(dict(raw_batch))
    tokens, mask = out["observation.language.tokens"], out["observation.language.attention_mask"]
    num_image_tokens = (cfg.backbone.image_size // cfg.backbone.patch_size) ** 2
    assert tokens.shape == (4, num_image_tokens + cfg.backbone.max_instruction_tokens)
    assert mask.dtype == torch.bool and mask[:, :num_image_tokens].all()
    tasks = raw_batch["task"]
    assert tasks[0] == tasks[1] != tasks[2]
    assert torch.equal(tokens[0], tokens[1]) and not torch.equal(tokens[0], tokens[2])
    assert (
        tokens[:, :num_image_tokens] == tokens[0, 0]
    ).all()  # the <image> placeholder, once per image token


def test_saved_pipelines_reload_for_evaluation(make_config, make_processors, raw_batch, tmp_path: Path):
    cfg = make_config()
    pre, post = make_processors(cfg)
    pre.save_pretrained(tmp_path)
    post.save_pretrained(tmp_path)
    # lerobot-eval's overrides; the custom steps rebuild from their JSON config (the tiny tokenizer offline)
    pre2, post2 = make_pre_post_processors(
        cfg,
        pretrained_path=str(tmp_path),
        preprocessor_overrides={
            "device_processor": {"device": "cpu"},
            "rename_observations_processor": {"rename_map": {}},
        },
    )
    expected, actual = pre(dict(raw_batch)), pre2(dict(raw_batch))
    for key, value in expected.items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(value, actual[key]), key
    action = torch.randn(4, 7)
    assert torch.equal(post(action), post2(action))


def test_finetuning_stat_overrides_keep_the_sharing(make_config, make_processors, raw_batch, tmp_path):
    """``lerobot-train --policy.path=...`` overrides the normaliser's stats with the raw dataset stats: the
    proprioception is normalised by our own step, so its numbers stay those of the checkpoint (never
    twice)."""
    cfg = make_config()
    pre, post = make_processors(cfg)
    pre.save_pretrained(tmp_path)
    post.save_pretrained(tmp_path)
    stats = {
        key: {name: torch.as_tensor(v).clone() for name, v in value.items()}
        for key, value in {
            STATE: {"mean": torch.full((15,), 0.5), "std": torch.full((15,), 2.0)},
            HISTORY: {"mean": torch.zeros(15), "std": torch.ones(15)},
            "action": {"min": -torch.ones(7), "max": torch.ones(7)},
        }.items()
    }
    pre2, _ = make_pre_post_processors(
        cfg,
        pretrained_path=str(tmp_path),
        preprocessor_overrides={
            "device_processor": {"device": "cpu"},
            "normalizer_processor": {"stats": stats},
        },
    )
    out, reference = pre2(dict(raw_batch)), pre(dict(raw_batch))
    for key in (STATE, HISTORY, TRACE):
        torch.testing.assert_close(out[key], reference[key])


def test_state_normalisation_other_than_identity_is_refused(make_config) -> None:
    from lerobot.configs import NormalizationMode

    mapping = {"VISUAL": NormalizationMode.IDENTITY, "STATE": NormalizationMode.MEAN_STD,
               "ENV": NormalizationMode.IDENTITY, "ACTION": NormalizationMode.MIN_MAX}  # fmt: skip
    from lerobot_subgoalvla.config_error import ConfigError

    with pytest.raises(ConfigError, match="STATE: IDENTITY"):
        make_config(normalization_mapping=mapping)


def test_postprocessor_inverts_the_action_normalisation(make_config, make_processors, raw_batch) -> None:
    pre, post = make_processors(make_config())
    normalised = pre(dict(raw_batch))["action"]  # (B, N, A) in [-1, 1] (MIN_MAX)
    assert normalised.min() >= -1 - 1e-5 and normalised.max() <= 1 + 1e-5
    torch.testing.assert_close(post(normalised[:, 0]), raw_batch["action"][:, 0], atol=1e-5, rtol=1e-5)


def test_tokenizer_step_config_round_trips() -> None:
    step = SubgoalVLATokenizerProcessorStep(
        tiny_dims={
            "text_hidden_size": 32,
            "text_num_layers": 4,
            "text_num_heads": 4,
            "text_intermediate_size": 64,
            "vision_hidden_size": 32,
            "vision_num_layers": 2,
            "vision_num_heads": 4,
            "image_size": 32,
            "patch_size": 8,
            "vocabulary": ["open", "the", "drawer"],
        },
        max_length=12,
    )
    clone = SubgoalVLATokenizerProcessorStep(**step.get_config())
    assert clone.get_config() == step.get_config() and clone.sequence_length == 16 + 12
    with pytest.raises(ValueError, match="exactly one of name_or_path / tiny_dims"):
        SubgoalVLATokenizerProcessorStep()
    old = {key: value for key, value in step.get_config()["tiny_dims"].items() if key != "vocabulary"}
    with pytest.raises(ValueError, match="saved before tiny vocabularies were stored"):
        SubgoalVLATokenizerProcessorStep(tiny_dims=old)


def test_unknown_words_are_named_once_per_instruction(
    make_config, make_processors, raw_batch, caplog
) -> None:
    pre, _ = make_processors(make_config())
    batch = dict(raw_batch)
    batch["task"] = [
        "open the drawer",
        "open the fridge quickly",
        "open the fridge quickly",
        "open the drawer",
    ]
    with caplog.at_level("WARNING"):
        pre(dict(batch))
        pre(dict(batch))
    warnings = [r.getMessage() for r in caplog.records if "never saw in training" in r.getMessage()]
    assert len(warnings) == 1 and "['fridge', 'quickly']" in warnings[0]
