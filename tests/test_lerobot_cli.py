"""LeRobot's own CLIs on our plugin: bad values reach the user as one line; every flag has a help."""

from __future__ import annotations

import logging
import os
import shutil
import subprocess

import pytest

ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}


def _run(command: list[str]) -> subprocess.CompletedProcess:
    if shutil.which(command[0]) is None:
        pytest.skip(f"{command[0]} is not installed")
    return subprocess.run(command, capture_output=True, text=True, env=ENV, timeout=300)


def test_bad_policy_value_names_the_flag_and_the_allowed_values(tmp_path) -> None:
    result = _run(["lerobot-train", "--policy.type=subgoalvla", "--policy.preset=huge",
                   "--dataset.repo_id=local/x", f"--dataset.root={tmp_path}"])  # fmt: skip
    assert result.returncode == 1
    assert "--policy.preset='huge' is not valid; allowed values: tiny, laptop, small, paper" in result.stderr
    assert "Couldn't instantiate" not in result.stderr


def test_bad_env_value_is_one_line_without_a_traceback() -> None:
    result = _run(["lerobot-eval", "--policy.type=subgoalvla", "--env.type=calvin", "--env.scene=foo"])
    assert result.returncode == 1
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("error: --env.scene='foo' is not valid; use one of: procedural, calvin_A")
    assert "ParsingError" not in result.stderr


def test_a_dataset_without_a_contract_feature_is_one_line_through_lerobot_train(tmp_path) -> None:
    """Found after parsing, in make_policy: the plugin's excepthook prints it without a traceback."""
    from helpers.lerobot_datasets import DEFAULT_REPO_ID, make_tiny_calvin_dataset

    root = tmp_path / "no_trace"
    make_tiny_calvin_dataset(
        root, num_episodes=1, episode_len=6, drop_features=("observation.subgoal_trace",)
    )
    result = _run(["lerobot-train", "--policy.type=subgoalvla", "--policy.preset=tiny",
                   "--policy.push_to_hub=false", f"--dataset.repo_id={DEFAULT_REPO_ID}",
                   f"--dataset.root={root}", f"--output_dir={tmp_path / 'out'}", "--steps=1",
                   "--wandb.enable=false"])  # fmt: skip
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert "error: the training dataset lacks observation.subgoal_trace" in last
    assert "subgoalvla-add-traces" in last


def test_every_policy_and_env_flag_has_a_one_line_help() -> None:
    import re

    result = _run(["lerobot-train", "--policy.type=subgoalvla", "--env.type=calvin", "--help"])
    lines = result.stdout.splitlines()
    flags, missing = 0, []
    for i, line in enumerate(lines):
        match = re.match(r"^  (--(?:policy|env)\.\S+)", line)
        if not match:
            continue
        flags += 1
        same_line = re.search(r"\S\s{2,}\S", line.strip())
        next_line = i + 1 < len(lines) and re.match(r"^\s{20,}[^\s-]", lines[i + 1])
        if not (same_line or next_line):
            missing.append(match.group(1))
    assert flags > 60 and not missing, f"flags without help: {missing}"
    assert "------" not in result.stdout  # no section banners standing in for help


def test_the_plugin_module_registers_everything_in_a_fresh_interpreter() -> None:
    """What LeRobot's discovery (and a user script) imports: policy, scheduler, processor steps and env."""
    import sys
    import textwrap

    script = textwrap.dedent(
        """
        import sys
        import lerobot_subgoalvla
        assert "torch" not in sys.modules  # the bare package stays light and registers nothing
        import lerobot_subgoalvla.plugin
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.envs.configs import EnvConfig
        from lerobot.optim.schedulers import LRSchedulerConfig
        from lerobot.processor import ProcessorStepRegistry
        assert PreTrainedConfig.get_choice_class("subgoalvla").__name__ == "SubgoalVLAConfig"
        assert EnvConfig.get_choice_class("calvin").__name__ == "CalvinEnvConfig"
        assert LRSchedulerConfig.get_choice_class("subgoalvla_two_stage_cosine")
        for name in ("subgoalvla_tokenizer_processor", "subgoalvla_proprio_normalizer"):
            assert ProcessorStepRegistry.get(name)
        assert "transformers.models.llava" not in sys.modules  # the model loads only when a policy is built
        print("ok")
        """
    )
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=ENV, timeout=300
    )
    assert result.returncode == 0 and result.stdout.strip().endswith("ok"), result.stderr[-2000:]


def _lerobot_main(module: str, argv: list[str], capsys: pytest.CaptureFixture) -> tuple[int, str]:
    """Run LeRobot's console script ``module`` in this process (parsing fails within a second, while a
    subprocess spends ~10 s importing); returns its exit code and the last line of stderr."""
    import importlib
    import sys

    import lerobot_subgoalvla.plugin  # noqa: F401 - what LeRobot's plugin discovery imports

    script = importlib.import_module(f"lerobot.scripts.{module}")
    capsys.readouterr()
    old_argv, sys.argv = sys.argv, [module.replace("_", "-"), *argv]
    try:
        with pytest.raises(SystemExit) as info:
            script.main()
    finally:
        sys.argv = old_argv
    return info.value.code, capsys.readouterr().err.strip().splitlines()[-1]


def _results_file_with_chain_3(tmp_path) -> str:
    from lerobot_subgoalvla.envs.calvin.env import official_chains
    from lerobot_subgoalvla.envs.calvin.evaluation.results import EpisodeResult, append_episode_result

    path = tmp_path / "results.jsonl"
    append_episode_result(path, EpisodeResult(3, official_chains()[3].tasks, 2))
    return str(path)


@pytest.mark.parametrize(
    ("flag", "code", "message"),
    [
        (
            "--env.task=foo",
            1,
            "error: --env.task='foo' is not valid; use 'lh_mtlc' or one of: rotate_red_block_",
        ),
        ("--env.episode_length=0", 1, "error: --env.episode_length=0 must be a positive integer"),
        ("--env.chain_stop=2000", 1, "0 <= chain_start < chain_stop <= 1000"),
        ("--env.resume=maybe", 1, "error: `env.resume`: Couldn't parse 'maybe' into a bool"),
        # a flag that does not exist: LeRobot's argparse prints its usage block, then this line (exit 2)
        ("--env.chains=x", 2, "lerobot-eval: error: unrecognized arguments: --env.chains=x"),
        ("--env.results_path={results}", 1, "already holds 1 chain(s) of [0, 1000); pass --env.resume=true"),
    ],
    ids=[
        "task-unknown",
        "episode-length-0",
        "chain-stop-too-large",
        "resume-not-a-bool",
        "unknown-flag",
        "results-path-holds-chains",
    ],  # fmt: skip
)
def test_bad_env_values_through_lerobot_eval_end_on_one_line(tmp_path, capsys, flag, code, message) -> None:
    flag = flag.format(results=_results_file_with_chain_3(tmp_path)) if "{results}" in flag else flag
    argv = ["--policy.type=subgoalvla", "--env.type=calvin", flag, f"--output_dir={tmp_path / 'eval'}"]
    got_code, last_line = _lerobot_main("lerobot_eval", argv, capsys)
    assert got_code == code and message in last_line
    assert not (tmp_path / "eval").exists()


def test_a_torchcodec_that_cannot_load_ffmpeg_is_reported_in_one_line(monkeypatch, caplog) -> None:
    """LeRobot's own probe, with torchcodec's loader failing as it does without FFmpeg's libraries."""
    import importlib

    from lerobot.utils import import_utils

    import lerobot_subgoalvla.plugin  # noqa: F401  (installs the filter)
    from lerobot_subgoalvla.decoder_probe import ONE_LINE

    real_import = importlib.import_module
    loader_report = "Could not load libtorchcodec. Likely causes:\n" + "\n".join(
        f"[start of libtorchcodec loading traceback]\nFFmpeg version {v}: libavutil.so.{v + 52}: cannot open"
        for v in (7, 6, 5, 4)
    )

    def failing_import(name: str, *args, **kwargs):
        if name == "torchcodec":
            raise RuntimeError(loader_report)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(importlib, "import_module", failing_import)
    with caplog.at_level(logging.WARNING, logger="lerobot.utils.import_utils"):
        assert import_utils.get_safe_default_video_backend() == "pyav"
    messages = [r.getMessage() for r in caplog.records if r.name == "lerobot.utils.import_utils"]
    assert messages == [ONE_LINE] and "\n" not in ONE_LINE
