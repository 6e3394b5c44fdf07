"""SubgoalVLA inside LeRobot: plugin discovery, ``lerobot-train`` (stages, checkpoints, resume, accelerate),
Hub errors.

The CLI tests run LeRobot's own console scripts as subprocesses on the tiny dataset, like a user would.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from helpers.lerobot_datasets import make_tiny_calvin_dataset
from lerobot.policies.factory import make_policy
from safetensors.torch import load_file

import lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla as modeling
from lerobot_subgoalvla.policies.subgoalvla.modeling_subgoalvla import SubgoalVLAPolicy

BIN = Path(sys.executable).parent
TRAIN_STEPS, SWITCH_STEP, LOG_FREQ = 16, 8, 8
LOG_LINE = re.compile(r"step:(\d+) .* loss:([0-9.]+) .* stage:([0-9.]+)")


def _env() -> dict[str, str]:
    return {
        **os.environ,
        "HF_HUB_OFFLINE": "1",
        "HF_DATASETS_OFFLINE": "1",
        "TOKENIZERS_PARALLELISM": "false",
    }


def _train_flags(dataset_root: Path, output_dir: Path, steps: int) -> list[str]:
    return [
        "--policy.type=subgoalvla",
        "--policy.preset=tiny",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        "--policy.optimizer_lr_heads=3e-3",
        f"--policy.stage2_start_step={SWITCH_STEP}",  # the DDP test overrides it (draccus: last flag wins)
        "--dataset.repo_id=local/tiny_calvin",
        f"--dataset.root={dataset_root}",
        "--dataset.video_backend=pyav",
        f"--output_dir={output_dir}",
        f"--steps={steps}",
        "--batch_size=4",
        "--num_workers=0",
        f"--log_freq={LOG_FREQ}",
        f"--save_freq={SWITCH_STEP}",
        "--wandb.enable=false",
    ]


def _run(command: list[str], timeout: int = 540) -> str:
    result = subprocess.run(command, capture_output=True, text=True, env=_env(), timeout=timeout, check=False)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-4000:]
    return output


def _logged(output: str) -> list[tuple[int, float, float]]:
    """(step, loss, stage) of every training log line (each an average over ``log_freq`` steps)."""
    return [(int(s), float(loss), float(stage)) for s, loss, stage in LOG_LINE.findall(output)]


def test_discovery_through_lerobots_plugin_hook_in_a_fresh_interpreter() -> None:
    code = (
        "import sys\n"
        "from lerobot.utils.import_utils import register_third_party_plugins\n"
        "from lerobot.configs import PreTrainedConfig\n"
        "assert 'subgoalvla' not in PreTrainedConfig.get_known_choices()\n"
        "assert not any(m.startswith('lerobot_subgoalvla') for m in sys.modules)\n"
        "register_third_party_plugins()\n"
        "from lerobot.policies.factory import get_policy_class, make_policy_config\n"
        "cfg = make_policy_config('subgoalvla', device='cpu')\n"
        "print(type(cfg).__name__, get_policy_class('subgoalvla').__name__)\n"
    )
    output = _run([sys.executable, "-c", code], timeout=300)
    assert "SubgoalVLAConfig SubgoalVLAPolicy" in output


@pytest.fixture(scope="module")
def trained_run(tiny_dataset_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """One short ``lerobot-train`` run: stage I for 8 steps, then stage II; checkpoints every 8 steps."""
    output_dir = tmp_path_factory.mktemp("train") / "run"
    output = _run([str(BIN / "lerobot-train"), *_train_flags(tiny_dataset_root, output_dir, TRAIN_STEPS)])
    return output_dir, output


def test_lerobot_train_lowers_the_loss_switches_stage_and_checkpoints(trained_run: tuple[Path, str]) -> None:
    output_dir, output = trained_run
    logged = _logged(output)
    assert [step for step, _, _ in logged] == [8, 16]
    (_, first_loss, first_stage), (_, last_loss, last_stage) = logged
    assert last_loss < first_loss
    assert (first_stage, last_stage) == (1.0, 2.0)  # one run, stage II from step 8 on
    assert "switching to stage2 after 8 optimizer steps" in output
    checkpoints = output_dir / "checkpoints"
    for step in ("000008", "000016"):
        model_dir = checkpoints / step / "pretrained_model"
        for name in (
            "config.json",
            "model.safetensors",
            "policy_preprocessor.json",
            "policy_postprocessor.json",
        ):
            assert (model_dir / name).is_file(), name
    weights = load_file(checkpoints / "000016" / "pretrained_model" / "model.safetensors")
    assert int(weights["optimizer_steps"]) == TRAIN_STEPS  # the stage counter is saved with the weights


def test_lerobot_train_resume_continues_from_the_last_checkpoint(trained_run: tuple[Path, str]) -> None:
    output_dir, _ = trained_run
    config_path = output_dir / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    _run(
        [
            str(BIN / "lerobot-train"),
            f"--config_path={config_path}",
            "--resume=true",
            f"--steps={TRAIN_STEPS + 2}",
        ]
    )
    weights = load_file(output_dir / "checkpoints" / "last" / "pretrained_model" / "model.safetensors")
    assert int(weights["optimizer_steps"]) == TRAIN_STEPS + 2
    reloaded = SubgoalVLAPolicy.from_pretrained(output_dir / "checkpoints" / "last" / "pretrained_model")
    assert reloaded.stage == "stage2"


@pytest.mark.slow
def test_stage_two_run_starts_from_a_stage_one_checkpoint(
    trained_run: tuple[Path, str], tiny_dataset_root, tmp_path
):
    """``--policy.path=<stage I checkpoint> --policy.stage=stage2``: LeRobot's fine-tuning path (processors
    reloaded
    with the dataset's statistics as overrides)."""
    output_dir, _ = trained_run
    checkpoint = output_dir / "checkpoints" / "000008" / "pretrained_model"
    flags = [
        f for f in _train_flags(tiny_dataset_root, tmp_path / "stage2", 2) if not f.startswith("--policy.")
    ]
    flags = [f for f in flags if not f.startswith(("--log_freq", "--save_freq"))] + [
        "--log_freq=2",
        "--save_freq=2",
    ]
    output = _run(
        [str(BIN / "lerobot-train"), f"--policy.path={checkpoint}", "--policy.stage=stage2", *flags]
    )
    assert [stage for _, _, stage in _logged(output)] == [2.0]
    weights = load_file(
        tmp_path / "stage2" / "checkpoints" / "000002" / "pretrained_model" / "model.safetensors"
    )
    assert int(weights["optimizer_steps"]) == SWITCH_STEP + 2  # the counter carries over from the checkpoint


@pytest.mark.slow
@pytest.mark.lerobot_contract
def test_lerobot_eval_runs_a_checkpoint_on_the_calvin_env(
    trained_run: tuple[Path, str], tmp_path: Path
) -> None:
    """The saved checkpoint + pipelines drive ``lerobot-eval --env.type=calvin`` (one short LH-MTLC chain)."""
    output_dir, _ = trained_run
    checkpoint = output_dir / "checkpoints" / "last" / "pretrained_model"
    flags = ["--env.type=calvin", "--env.task=lh_mtlc", "--env.chain_stop=1", "--env.episode_length=10"]
    flags += [
        "--eval.n_episodes=1",
        "--eval.batch_size=1",
        "--policy.device=cpu",
        f"--output_dir={tmp_path / 'eval'}",
    ]
    _run([str(BIN / "lerobot-eval"), f"--policy.path={checkpoint}", *flags])
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1


@pytest.mark.slow
def test_accelerate_launch_two_cpu_processes(tiny_dataset_root: Path, tmp_path: Path) -> None:
    """DDP over gloo on the CPU, across the stage switch (the frozen backbone gets no gradient in stage II).

    ``accelerate launch --cpu --num_processes 2`` starts ONE process (accelerate's simple launcher); on a
    CPU-only machine ``--multi_gpu --num_processes 2`` starts two torchrun workers and LeRobot's
    ``Accelerator(cpu=True)`` makes them a gloo process group.
    """
    output_dir = tmp_path / "ddp"
    flags = [
        f
        for f in _train_flags(tiny_dataset_root, output_dir, 4)
        if not f.startswith(("--log_freq", "--save_freq"))
    ]
    flags += ["--log_freq=2", "--save_freq=4", "--policy.stage2_start_step=2"]
    launcher = [
        str(BIN / "accelerate"),
        "launch",
        "--multi_gpu",
        "--num_processes",
        "2",
        "--num_machines",
        "1",
    ]
    output = _run(
        [*launcher, "--mixed_precision", "no", "--dynamo_backend", "no", str(BIN / "lerobot-train"), *flags]
    )
    assert "Effective batch size: 4 x 2 = 8" in output
    assert [stage for _, _, stage in _logged(output)] == [1.0, 2.0]
    weights = load_file(output_dir / "checkpoints" / "000004" / "pretrained_model" / "model.safetensors")
    assert int(weights["optimizer_steps"]) == 4


@pytest.mark.parametrize(
    ("missing", "named"),
    [
        (("observation.subgoal_trace",), "observation.subgoal_trace"),
        (("observation.state_history", "observation.subgoal_trace"), "observation.state_history"),
        (("observation.images.static", "observation.images.gripper"), "a camera"),
    ],
)
def test_a_dataset_without_a_contract_feature_gets_one_line(
    tmp_path: Path, make_config, missing: tuple[str, ...], named: str
) -> None:
    dataset = make_tiny_calvin_dataset(tmp_path / "ds", num_episodes=1, episode_len=3, drop_features=missing)
    with pytest.raises(ValueError) as info:
        make_policy(make_config(), ds_meta=dataset.meta)  # what lerobot-train calls
    message = str(info.value)
    assert all(key in message for key in missing if "images" not in key) and named in message
    assert "subgoalvla-add-traces" in message and "\n" not in message


def test_loading_a_hub_id_offline_fails_with_one_clear_line() -> None:
    with pytest.raises(OSError) as info:
        SubgoalVLAPolicy.from_pretrained("someone/subgoalvla_calvin")
    message = str(info.value)
    assert "HF_HUB_OFFLINE=1" in message and "local checkpoint directory" in message and "\n" not in message


def test_training_that_would_push_fails_before_training_when_offline(make_config, tiny_dataset) -> None:
    with pytest.raises(
        OSError, match=r"push_to_hub=true .*HF_HUB_OFFLINE=1 is set; train with --policy.push_to_hub=false"
    ):
        make_policy(
            make_config(push_to_hub=True, repo_id="someone/subgoalvla_calvin"), ds_meta=tiny_dataset.meta
        )


def test_push_to_hub_offline_fails_and_online_uploads_a_model_card(
    make_config, make_policy_and_processors, monkeypatch: pytest.MonkeyPatch
) -> None:
    policy, _, _ = make_policy_and_processors(make_config())
    with pytest.raises(OSError, match=r"HF_HUB_OFFLINE=1 is set; save locally with policy.save_pretrained"):
        policy.push_to_hub("someone/subgoalvla_calvin")

    uploaded: dict[str, list[str]] = {}

    class FakeApi:
        def __init__(self, *args, **kwargs) -> None:
            pass

        def create_repo(self, repo_id: str, **kwargs):
            return type("Repo", (), {"repo_id": repo_id})()

        def upload_folder(self, repo_id: str, folder_path: Path, **kwargs) -> str:
            uploaded[repo_id] = sorted(os.listdir(folder_path))
            card = Path(folder_path) / "README.md"
            uploaded["card"] = [card.read_text()]
            return f"https://huggingface.co/{repo_id}"

    import huggingface_hub
    import lerobot.utils.hub

    monkeypatch.setattr(modeling, "is_offline_mode", lambda: False)
    monkeypatch.setattr(lerobot.utils.hub, "HfApi", FakeApi)
    monkeypatch.setattr(huggingface_hub.ModelCard, "validate", lambda self, *a, **k: None)  # no network
    url = policy.push_to_hub(
        "someone/subgoalvla_calvin", card_kwargs={"dataset_repo_id": "someone/calvin_d_d"}
    )
    assert url.endswith("someone/subgoalvla_calvin")
    assert uploaded["someone/subgoalvla_calvin"] == ["README.md", "config.json", "model.safetensors"]
    assert "subgoalvla" in uploaded["card"][0] and "someone/calvin_d_d" in uploaded["card"][0]


def test_checkpoint_directory_loads_through_lerobots_factory(trained_run: tuple[Path, str]) -> None:
    """``lerobot-eval --policy.path=<ckpt>`` path: config from JSON, weights from safetensors, offline."""
    from lerobot.configs import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class

    output_dir, _ = trained_run
    path = output_dir / "checkpoints" / "000016" / "pretrained_model"
    cfg = PreTrainedConfig.from_pretrained(path)
    policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg)
    saved = load_file(path / "model.safetensors")
    for key, value in policy.state_dict().items():
        if key in saved:
            assert torch.equal(value, saved[key]), key


@pytest.mark.slow
def test_sigkill_after_a_checkpoint_then_resume_continues_that_run(tiny_dataset_root: Path, tmp_path) -> None:
    """A run killed after a checkpoint and resumed with ``--resume=true`` equals one uninterrupted run.

    LeRobot 0.6.1 restores the step, the weights, the optimizer and scheduler state, the sampler's data order
    (a function of seed and epoch) and the RNG states; its new DataLoader iterator then draws once more from
    torch's global RNG. The policy's training draws are keyed by (training_seed, step) instead of that stream
    (``SubgoalVLAPolicy._step_rng``), so the resumed weights are bit-identical (docs/errors.md).
    """
    import signal
    import time

    def flags(output_dir: Path) -> list[str]:
        overrides = ["--save_freq=2", "--log_freq=1", "--policy.stage2_start_step=3", "--seed=7"]
        return [*_train_flags(tiny_dataset_root, output_dir, 6), *overrides]  # draccus: the last flag wins

    uninterrupted = _run([str(BIN / "lerobot-train"), *flags(tmp_path / "a")])
    killed = tmp_path / "b"
    last = killed / "checkpoints" / "last"
    process = subprocess.Popen([str(BIN / "lerobot-train"), *flags(killed)], env=_env(),
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    deadline = time.monotonic() + 300
    while (
        process.poll() is None
        and time.monotonic() < deadline
        and not (last.is_symlink() and os.readlink(last).endswith("000002"))
    ):
        time.sleep(0.01)
    process.send_signal(signal.SIGKILL)
    assert process.wait() == -signal.SIGKILL and not (killed / "checkpoints" / "000004").exists()
    config_path = last / "pretrained_model" / "train_config.json"
    resumed = _run([str(BIN / "lerobot-train"), f"--config_path={config_path}", "--resume=true"])
    assert "Resuming data order at epoch 0, sample 8" in resumed  # 2 steps x batch 4
    assert [step for step, _, _ in _logged(resumed)] == [3, 4, 5, 6]
    assert [stage for _, _, stage in _logged(resumed)] == [stage for _, _, stage in _logged(uninterrupted)][
        2:
    ]

    def state(run: Path, step: str) -> tuple[dict, dict, dict]:
        checkpoint = run / "checkpoints" / step
        names = ("training_step.json", "scheduler_state.json", "optimizer_param_groups.json")
        meta = {name: json.loads((checkpoint / "training_state" / name).read_text()) for name in names}
        weights = load_file(checkpoint / "pretrained_model" / "model.safetensors")
        return weights, load_file(checkpoint / "training_state" / "optimizer_state.safetensors"), meta

    for step in ("000002", "000006"):
        (weights_a, optim_a, meta_a), (weights_b, optim_b, meta_b) = (
            state(tmp_path / "a", step),
            state(killed, step),
        )
        assert meta_a == meta_b, step  # step counter, scheduler, learning rates: identical
        assert sorted(optim_a) == sorted(optim_b) and sorted(weights_a) == sorted(weights_b)
        assert all(torch.isfinite(w.float()).all() for w in weights_b.values())
        assert all(torch.equal(weights_a[k], weights_b[k]) for k in weights_a), step
        assert all(torch.equal(optim_a[k], optim_b[k]) for k in optim_a), step
    assert int(weights_b["optimizer_steps"]) == 6
