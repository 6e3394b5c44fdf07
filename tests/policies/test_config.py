"""SubgoalVLAConfig: presets, CLI overrides, exact save/reload, validation messages, LeRobot presets."""

from __future__ import annotations

import draccus
import pytest
import torch
from draccus.utils import ParsingError
from lerobot.configs import FeatureType, PolicyFeature, PreTrainedConfig

from lerobot_subgoalvla.config_error import ConfigError
from lerobot_subgoalvla.contract.metadata import ProprioMetadata
from lerobot_subgoalvla.contract.window import TraceWindow
from lerobot_subgoalvla.policies.subgoalvla.configuration_subgoalvla import SubgoalVLAConfig


def parse(*args: str) -> SubgoalVLAConfig:
    """Parse CLI-style flags the way ``lerobot-train --policy.type=subgoalvla --policy.<flag>`` does.

    draccus wraps the config's ValueError in a ParsingError; re-raise the ValueError the user sees below it.
    """
    try:
        return draccus.parse(SubgoalVLAConfig, args=["--device=cpu", *args])
    except ParsingError as error:
        if isinstance(error.__cause__, ValueError):
            raise error.__cause__ from None
        raise


def test_paper_preset_carries_the_papers_values() -> None:
    cfg = parse("--preset=paper")
    assert cfg.backbone.name_or_path == "llava-hf/llava-1.5-7b-hf"
    assert cfg.backbone.layer is None  # k = m // 2, resolved from the loaded model
    assert cfg.backbone.freeze_vision_tower
    for head in (cfg.planner, cfg.generator):  # DiT-B (table 5), tables 6-8
        assert (head.hidden_size, head.depth, head.num_heads) == (768, 12, 12)
        assert (head.num_train_timesteps, head.label_dropout, head.l2_weight) == (8, 0.1, 0.001)
        assert head.repeated_diffusion_steps == 8
    for attn in (cfg.planner_attention, cfg.generator_attention):  # PCA: 3 layers, 8 heads (table 5)
        assert (attn.num_layers, attn.num_heads) == (3, 8)
    assert (cfg.state_history_len, cfg.subgoal_trace_len, cfg.chunk_size) == (15, 8, 15)
    assert (cfg.optimizer_lr_projector, cfg.optimizer_lr_llm, cfg.optimizer_lr_heads) == (1e-5, 2e-5, 1e-4)
    assert (cfg.scheduler_warmup_ratio, cfg.optimizer_weight_decay, cfg.scheduler_decay_lr) == (
        0.05,
        0.01,
        3e-6,
    )
    assert cfg.planner.guidance_scale > 1.0  # "s > 1" (appendix B.1)
    # a pretrained backbone brings its own architecture: no tiny dimensions are filled in
    assert cfg.backbone.text_hidden_size is None and cfg.backbone.image_size is None


def test_presets_differ_and_explicit_flags_win() -> None:
    tiny, small = parse("--preset=tiny"), parse("--preset=small")
    assert tiny.backbone.name_or_path is None and tiny.backbone.text_num_layers == 4
    assert small.backbone.name_or_path == "llava-hf/llava-interleave-qwen-0.5b-hf"
    assert tiny.planner.hidden_size < small.planner.hidden_size
    cfg = parse("--preset=paper", "--planner.depth=4", "--generator_attention.num_heads=4")
    assert cfg.planner.depth == 4 and cfg.planner.hidden_size == 768  # the flag wins, the rest is the preset
    assert cfg.generator_attention.num_heads == 4 and cfg.generator_attention.num_layers == 3
    custom = parse("--preset=tiny", "--backbone.name_or_path=/models/my_llava")
    assert custom.backbone.text_hidden_size is None  # no tiny dims for a pretrained checkpoint


def test_saved_config_reloads_exactly(tmp_path) -> None:
    cfg = parse("--preset=tiny", "--planner.depth=3", "--stage2_start_step=7", "--n_action_steps=5")
    cfg.input_features = {"observation.state": PolicyFeature(type=FeatureType.STATE, shape=(15,))}
    cfg.save_pretrained(tmp_path)
    loaded = PreTrainedConfig.from_pretrained(tmp_path)
    assert isinstance(loaded, SubgoalVLAConfig)
    assert loaded == cfg


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--preset=huge"], "allowed values: tiny, laptop, small, paper"),
        (["--feature_aggregation=sum"], "allowed values: proprio_xattn, mean, max, attn"),
        (["--stage=stage3"], "allowed values: stage1, stage2"),
        (["--backbone.torch_dtype=int8"], "allowed values: float32, bfloat16, float16"),
        (["--n_action_steps=16"], "must be <= --policy.chunk_size=15"),
        (["--chunk_size=0"], "chunk_size must be positive"),
        (["--backbone.layer=5"], "must be in [1, 4]"),
        (["--planner.guidance_scale=0.5"], "guidance_scale must be >= 1"),
        (["--generator.num_inference_steps=10"], "must be <= --policy.generator.num_train_timesteps=8"),
        (["--planner.hidden_size=30", "--planner.num_heads=4"], "must be divisible by"),
        (["--preset=paper", "--backbone.image_size=64"], "only applies to the tiny backbone"),
        (["--stage2_start_step=-1"], "stage2_start_step must be >= 0"),
        (["--use_planner=false", "--stage=stage2"], "w/o SP"),
        (["--preset=tiny", "--backbone.image_size=30"], "must be a multiple of"),
    ],
)
def test_bad_values_are_rejected_with_the_allowed_values(flags: list[str], message: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse(*flags)
    assert message in str(info.value)
    assert "\n" not in str(info.value)


def _features(*keys: str) -> dict[str, PolicyFeature]:
    shapes = {
        "observation.state": (FeatureType.STATE, (15,)),
        "observation.images.static": (FeatureType.VISUAL, (3, 32, 32)),
        "observation.images.gripper": (FeatureType.VISUAL, (3, 16, 16)),
        "observation.state_history": (FeatureType.STATE, (15, 15)),
        "observation.subgoal_trace": (FeatureType.STATE, (8, 15)),
        "observation.environment_state": (FeatureType.ENV, (24,)),
        "observation.image": (FeatureType.VISUAL, (3, 32, 32)),
        "observation.images.a": (FeatureType.VISUAL, (3, 32, 32)),
        "observation.images.b": (FeatureType.VISUAL, (3, 16, 16)),
        "observation.images.c": (FeatureType.VISUAL, (3, 24, 24)),
    }
    return {key: PolicyFeature(type=shapes[key][0], shape=shapes[key][1]) for key in keys}


def test_validate_features_accepts_an_env_without_trace_or_history() -> None:
    cfg = parse()
    cfg.input_features = _features(
        "observation.state", "observation.images.static", "observation.images.gripper"
    )
    cfg.output_features = {"action": PolicyFeature(type=FeatureType.ACTION, shape=(7,))}
    cfg.validate_features()  # evaluation: the env gives cameras + state, the policy builds the history


def test_validate_features_names_everything_missing_at_once() -> None:
    cfg = parse()
    cfg.input_features = _features("observation.environment_state")
    with pytest.raises(ValueError) as info:
        cfg.validate_features()
    message = str(info.value)
    assert "observation.state" in message and "a camera" in message and "'action'" in message
    assert "\n" not in message


@pytest.mark.parametrize(
    "cameras",
    [("observation.image",), ("observation.images.a", "observation.images.b", "observation.images.c")],
)
def test_any_number_of_cameras_in_feature_order_or_chosen(cameras: tuple[str, ...]) -> None:
    cfg = parse()
    cfg.input_features = _features("observation.state", *cameras)
    cfg.output_features = {"action": PolicyFeature(type=FeatureType.ACTION, shape=(4,))}
    cfg.validate_features()
    assert cfg.image_features_in_order == list(cameras)
    chosen = parse(f"--camera_keys=[{cameras[-1]}]")
    chosen.input_features, chosen.output_features = cfg.input_features, cfg.output_features
    chosen.validate_features()
    assert chosen.image_features_in_order == [cameras[-1]]
    wrong = parse("--camera_keys=[observation.images.top]")
    wrong.input_features, wrong.output_features = cfg.input_features, cfg.output_features
    with pytest.raises(ValueError, match="not cameras of the dataset/env; its cameras are"):
        wrong.validate_features()


def _dataset_features(state_dim: int = 15, **metadata: object) -> dict:
    window = TraceWindow(15, 14, 8, 1)
    features = {
        "observation.state": {"dtype": "float32", "shape": (state_dim,)},
        "observation.image": {"dtype": "video", "shape": (32, 32, 3)},
        "observation.state_history": {"dtype": "float32", "shape": (15, state_dim)},
        "observation.subgoal_trace": {"dtype": "float32", "shape": (8, state_dim)},
        "action": {"dtype": "float32", "shape": (4,)},
    }
    return ProprioMetadata(window, 30, **metadata).attach(features)


def test_dataset_features_need_state_camera_history_and_trace_named_at_once() -> None:
    features = _dataset_features()
    for key in ("observation.state_history", "observation.subgoal_trace", "observation.image"):
        features.pop(key)
    with pytest.raises(ValueError) as info:
        parse().set_dataset_feature_metadata(features)
    message = str(info.value)
    assert "observation.state_history" in message and "observation.subgoal_trace" in message
    assert "a camera" in message and "subgoalvla-add-traces" in message


def test_dataset_window_and_angles_are_adopted_and_checked() -> None:
    cfg = parse()
    cfg.set_dataset_feature_metadata(_dataset_features(angle_dims=(3,), angle_home=(3.0,)))
    assert (cfg.state_stride, cfg.subgoal_trace_start) == (1, 14)
    assert cfg.state_angle_dims == (3,) and cfg.state_angle_home == (3.0,)
    plain = parse()
    plain.set_dataset_feature_metadata(_dataset_features())
    assert plain.state_angle_dims == ()  # no angle settings: plain normalisation
    with pytest.raises(
        ValueError, match="subgoal_trace_start=20 but the dataset's trace columns were cut with 14"
    ):
        parse("--subgoal_trace_start=20").set_dataset_feature_metadata(_dataset_features())
    with pytest.raises(ValueError, match="do not fit the 2-dim observation.state"):
        parse().set_dataset_feature_metadata(
            _dataset_features(state_dim=2, angle_dims=(3,), angle_home=(0.0,))
        )
    with pytest.raises(ValueError, match="state_history_len=10"):
        parse("--state_history_len=10").set_dataset_feature_metadata(_dataset_features())


def test_a_dataset_without_window_metadata_gets_one_line_saying_how_to_update_it() -> None:
    features = _dataset_features()
    del features["observation.subgoal_trace"]["info"]
    with pytest.raises(ValueError, match="carries no window metadata") as info:
        parse().set_dataset_feature_metadata(features)
    assert "subgoalvla-convert-calvin" in str(info.value) and "\n" not in str(info.value)


def test_angle_flags_must_pair_up() -> None:
    with pytest.raises(ConfigError, match="one value per --policy.state_angle_dims entry"):
        parse("--state_angle_dims=[3,4]", "--state_angle_home=[0.0]")


def test_delta_indices_and_stage_schedule() -> None:
    cfg = parse("--stage2_start_step=5")
    assert cfg.observation_delta_indices is None  # the history is precomputed, cameras decode once
    assert cfg.action_delta_indices == list(range(15))
    assert [cfg.stage_at(s) for s in (0, 4, 5, 100)] == ["stage1", "stage1", "stage2", "stage2"]
    assert parse("--stage=stage2").stage_at(0) == "stage2"
    assert (
        parse("--stage=stage2", "--stage2_start_step=5").stage_at(0) == "stage2"
    )  # continuing a stage I ckpt


def _lr_curve(cfg, steps: int) -> list[float]:
    optimizer_cfg = cfg.get_optimizer_preset()
    param = torch.nn.Parameter(torch.zeros(1))
    optimizer = optimizer_cfg.build([{"params": [param], "lr": cfg.optimizer_lr_heads}])
    scheduler = cfg.get_scheduler_preset().build(optimizer, num_training_steps=steps)
    lrs = []
    for _ in range(steps):
        lrs.append(optimizer.param_groups[0]["lr"])
        optimizer.step()
        scheduler.step()
    return lrs


def test_optimizer_and_scheduler_presets_follow_table_8() -> None:
    cfg = parse("--preset=paper")
    optimizer_cfg = cfg.get_optimizer_preset()
    assert optimizer_cfg.type == "adamw" and optimizer_cfg.weight_decay == 0.01
    lrs = _lr_curve(cfg, 200)
    peak = max(lrs)
    assert lrs.index(peak) == 9  # warmup = 5% of the 200 steps (steps 0..9 ramp up to the peak)
    assert peak == pytest.approx(1e-4, rel=0.01)
    assert lrs[-1] == pytest.approx(3e-6, rel=0.05)  # cosine decays to 3e-6 at the end of the run


def test_stage_two_restarts_the_schedule_at_the_switch() -> None:
    """A one-run switch gives stage II its own warmup and cosine from the peak (not 27 % of it)."""
    cfg = parse("--preset=paper", "--stage2_start_step=120")
    lrs = _lr_curve(cfg, 200)
    assert lrs[119] == pytest.approx(3e-6, rel=0.05)  # stage I ends at its floor
    assert max(lrs[120:]) == pytest.approx(1e-4, rel=0.01)  # stage II climbs back to the peak
    assert lrs[-1] == pytest.approx(3e-6, rel=0.05)


def test_short_run_presets_use_the_short_run_recipe() -> None:
    for preset in ("tiny", "laptop"):
        cfg = parse(f"--preset={preset}")
        assert (cfg.optimizer_lr_heads, cfg.optimizer_lr_llm, cfg.optimizer_lr_projector) == (
            1e-3,
            3e-4,
            3e-4,
        )
        assert cfg.dtype == "float32"
    laptop = parse("--preset=laptop")
    assert not laptop.backbone.freeze_vision_tower  # a random vision tower has to learn
    assert laptop.backbone.image_size > parse("--preset=tiny").backbone.image_size
    assert parse() == laptop  # the default: the smallest preset that learns from its cameras
    assert parse("--preset=laptop", "--optimizer_lr_heads=5e-4").optimizer_lr_heads == 5e-4  # flags win


def test_large_presets_train_in_mixed_precision_with_float32_weights() -> None:
    for preset in ("small", "paper"):
        cfg = parse(f"--preset={preset}")
        assert cfg.dtype == "bfloat16"  # lerobot-train: accelerate bf16 autocast
        assert cfg.backbone.torch_dtype == "float32"  # master weights stay float32
