"""vector.py: our episode-end freeze behaves like LeRobot's, and an env worker process stays light."""

from __future__ import annotations

import pickle
import subprocess
import sys
import textwrap

import numpy as np
from lerobot.envs import utils as lerobot_env_utils

from lerobot_subgoalvla.envs.calvin.env import CalvinEnv
from lerobot_subgoalvla.envs.calvin.protocol import NEW_ROLLOUT_OPTION
from lerobot_subgoalvla.envs.calvin.vector import FrozenAfterEpisodeEnd, make_frozen_env

SMALL = {"task": "open_drawer", "static_size": 16, "gripper_size": 16, "episode_length": 3}


def test_new_rollout_option_is_lerobots() -> None:
    assert NEW_ROLLOUT_OPTION == lerobot_env_utils.NEW_ROLLOUT_OPTION


def _run(wrapper_cls: type) -> list[tuple]:
    """Reset, five steps past a 3-step episode, an autoreset, a new rollout: what the wrapper returns."""
    env = wrapper_cls(CalvinEnv(**SMALL))
    trace = []
    obs, _ = env.reset(seed=3, options={NEW_ROLLOUT_OPTION: True})
    trace.append(("reset", obs["agent_pos"].copy()))
    for _ in range(5):
        obs, reward, terminated, truncated, _ = env.step(np.zeros(7, dtype=np.float32))
        trace.append(("step", obs["agent_pos"].copy(), reward, terminated, truncated))
    obs, _ = env.reset()  # gymnasium's autoreset: stays frozen
    trace.append(("autoreset", obs["agent_pos"].copy()))
    obs, _ = env.reset(seed=4, options={NEW_ROLLOUT_OPTION: True})
    trace.append(("new rollout", obs["agent_pos"].copy(), env.is_frozen))
    env.close()
    return trace


def test_frozen_after_episode_end_matches_lerobots_wrapper() -> None:
    ours, theirs = _run(FrozenAfterEpisodeEnd), _run(lerobot_env_utils.FreezeAfterEpisodeEnd)
    assert len(ours) == len(theirs)
    for a, b in zip(ours, theirs, strict=True):
        assert a[0] == b[0]
        for x, y in zip(a[1:], b[1:], strict=True):
            np.testing.assert_array_equal(x, y)
    steps = [t for t in ours if t[0] == "step"]
    assert steps[2][4] and steps[3][2] == 0.0 and steps[4][4]  # truncated at 3, then replayed with reward 0
    np.testing.assert_array_equal(steps[2][1], steps[4][1])


def test_env_worker_imports_neither_torch_nor_lerobot() -> None:
    """What a forkserver worker does: unpickle the env factory, build the env, reset it."""
    factory = pickle.dumps(make_frozen_env)
    script = textwrap.dedent(
        f"""
        import pickle, sys
        factory = pickle.loads({factory!r})
        env = factory(**{SMALL!r})
        env.reset(seed=0)
        heavy = sorted(m for m in ("torch", "transformers", "lerobot") if m in sys.modules)
        print(",".join(heavy) or "light")
        """
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert result.stdout.strip().splitlines()[-1] == "light"


def test_light_commands_answer_help_without_torch() -> None:
    """The commands that need no model import neither torch nor LeRobot (their --help answers in well under 1
    s;
    benchmarks/import_time.py measures it)."""
    modules = (
        "lerobot_subgoalvla.envs.calvin.evaluation.report",
        "lerobot_subgoalvla.envs.calvin.evaluation.chains",
        "lerobot_subgoalvla.demo_report",
        "lerobot_subgoalvla.datasets_conversion.generate_calvin",
    )
    script = textwrap.dedent(
        f"""
        import contextlib, importlib, io, sys
        for name in {modules!r}:
            sys.argv = [name, "--help"]
            with contextlib.suppress(SystemExit), contextlib.redirect_stdout(io.StringIO()):
                importlib.import_module(name).main()
        heavy = [m for m in ("torch", "transformers", "lerobot", "matplotlib") if m in sys.modules]
        print(",".join(heavy) or "light")
        """
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert result.stdout.strip().splitlines()[-1] == "light"
