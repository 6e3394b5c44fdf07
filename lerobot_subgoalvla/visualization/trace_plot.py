"""What SubgoalVLA planned against what the robot did, in any LeRobot env: its predicted subgoal traces (paper
section 4.2, eq. 3) plotted beside the executed ``observation.state``, one panel per state dimension.

The rollout is LeRobot's own evaluation loop (``lerobot.scripts.lerobot_eval.rollout``, the function
``lerobot-eval`` runs, with the env's and the policy's processors), so the policy sees exactly what it sees at
evaluation; after every ``select_action`` the policy's ``last_subgoal_trace`` is read, and each new one (a new
chunk was planned) is mapped back to state units with the checkpoint's own statistics. A trace planned at step
``t`` holds the states the planner expects at steps ``t + start + k * stride`` (``k = 0 .. M - 1``, the
window the policy was trained with, ``contract/window.py``), so it is drawn at those steps: where the
executed line runs through the dots, the generator followed its plan.

This works for any env LeRobot builds (``--env-type metaworld``, ``calvin``, ...); CALVIN's ghost robots drawn
into the camera image are ``render_traces``.

Command::

    subgoalvla-plot-traces --policy-path $RUN/train/checkpoints/last/pretrained_model \\
        --env-type metaworld --task reach-v3 --seed 1000 --output trace_plot.png

Dimension legend: ``T`` executed steps, ``M`` trace states, ``p`` state dim.
"""

from __future__ import annotations

import io
import logging
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lerobot_subgoalvla.cli_errors import OneLineArgumentParser, user_errors
from lerobot_subgoalvla.contract.keys import STATE_KEY

logger = logging.getLogger(__name__)


@dataclass
class TraceRollout:
    """One episode: the executed states and every trace planned on the way.

    Attributes:
        task: the env's instruction.
        states: ``(T, p)`` ``observation.state`` at each executed step.
        plans: ``(step, (M, p) trace in state units)`` for every planned chunk.
        trace_steps: ``(M,)`` offsets of the trace states from the planning step (``start + k * stride``).
        success: whether the env reported success.
    """

    task: str
    states: np.ndarray
    plans: list[tuple[int, np.ndarray]]
    trace_steps: np.ndarray
    success: bool


def env_config(env_type: str, task: str) -> Any:
    """LeRobot's env config of type ``env_type`` for ``task``.

    Raises:
        ValueError: ``env_type`` is not a registered LeRobot env type (the message lists them).
    """
    from lerobot.envs.configs import EnvConfig

    try:
        env_cls = EnvConfig.get_choice_class(env_type)
    except KeyError:
        known = ", ".join(sorted(EnvConfig.get_known_choices()))
        raise ValueError(f"--env-type {env_type}: not a LeRobot env type; choose one of {known}") from None
    return env_cls(task=task)


def make_single_env(env_cfg: Any) -> Any:
    """LeRobot's vector env of ``env_cfg`` with one sub-env (the first task's)."""
    from lerobot.envs.factory import make_env

    suites = make_env(env_cfg, n_envs=1)
    return next(iter(next(iter(suites.values())).values()))


def rollout_traces(
    policy: Any, preprocessor: Any, postprocessor: Any, env: Any, env_cfg: Any, seed: int
) -> TraceRollout:
    """One episode of ``policy`` in the single-env vector ``env`` through LeRobot's evaluation loop, with the
    traces it planned (module docstring).

    Raises:
        ValueError: the policy has no planner (no trace is ever predicted).
    """
    import torch
    from lerobot.envs.factory import make_env_pre_post_processors
    from lerobot.scripts.lerobot_eval import rollout

    from lerobot_subgoalvla.visualization.checkpoint import unnormalize_state

    config = policy.config
    if getattr(config, "use_planner", True) is False:
        raise ValueError(
            "this checkpoint was trained without the subgoal planner (use_planner=false): no traces"
        )
    plans: list[tuple[int, np.ndarray]] = []
    calls, last = 0, None

    def on_action(acting_policy: Any) -> None:  # called after every select_action
        nonlocal calls, last
        trace = acting_policy.last_subgoal_trace
        if trace is not None and trace is not last:  # a new chunk (and trace) was planned at this step
            plans.append((calls, unnormalize_state(preprocessor, trace[0].float().cpu()).numpy()))
            last = trace
        calls += 1

    env_preprocessor, env_postprocessor = make_env_pre_post_processors(env_cfg, config)
    torch.manual_seed(seed)
    policy.eval()
    data = rollout(
        env, policy, env_preprocessor, env_postprocessor, preprocessor, postprocessor, seeds=[seed],
        return_observations=True, predicted_latents_callback=on_action,
    )  # fmt: skip
    done = data["done"][0].numpy()
    steps = int(np.argmax(done)) + 1 if done.any() else len(done)
    states = data["observation"][STATE_KEY][0, :steps].float().numpy()  # (T, p)
    offsets = config.subgoal_trace_start + config.state_stride * np.arange(config.subgoal_trace_len)
    return TraceRollout(
        task=str(env.call("task_description")[0]),
        states=states,
        plans=plans,
        trace_steps=offsets,
        success=bool(data["success"][0, :steps].any()),
    )


def plot_trace_rollout(result: TraceRollout, path: Path) -> None:
    """One panel per state dimension: the executed state (black) and each planned trace (dots at the steps it
    is meant for, coloured from the first chunk to the last)."""
    from matplotlib import colormaps
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from lerobot_subgoalvla.atomic_files import atomic_write

    dims = result.states.shape[1]
    fig = Figure(figsize=(9, 1.8 * dims + 0.8), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(dims, 1, sharex=True, squeeze=False)[:, 0]
    colours = colormaps["viridis"](np.linspace(0, 1, max(len(result.plans), 1)))
    for d, ax in enumerate(axes):
        ax.plot(np.arange(len(result.states)), result.states[:, d], color="black", lw=1.5, label="executed")
        for (step, trace), colour in zip(result.plans, colours, strict=False):
            ax.plot(step + result.trace_steps, trace[:, d], "o-", ms=2.5, lw=0.8, color=colour, alpha=0.8)
        ax.set_ylabel(f"state[{d}]")
    axes[0].legend(loc="upper right")
    axes[-1].set_xlabel("env step")
    outcome = "success" if result.success else "no success"
    fig.suptitle(
        f"{result.task!r}: {len(result.plans)} planned traces, {outcome} after {len(result.states)} steps"
    )
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    atomic_write(path, buffer.getvalue())


def _parse_args(argv: list[str] | None) -> Any:
    parser = OneLineArgumentParser(
        prog="subgoalvla-plot-traces",
        description="Roll a SubgoalVLA checkpoint out in a LeRobot env; plot its traces beside the state",
    )
    parser.add_argument("--policy-path", required=True, help="checkpoint dir (config.json + processors)")
    parser.add_argument("--env-type", required=True, help="LeRobot env type, e.g. metaworld or calvin")
    parser.add_argument("--task", required=True, help="the env's task, e.g. reach-v3")
    parser.add_argument("--seed", type=int, default=1000, help="the episode's seed")
    parser.add_argument("--output", type=Path, required=True, help="the figure to write (.png)")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """``subgoalvla-plot-traces``: write the trace figure of one episode to ``--output``."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    with user_errors(logger):
        args = _parse_args(argv)
        if args.output.suffix != ".png":
            raise ValueError(f"--output {args.output}: use a .png file name")
        import lerobot_subgoalvla.plugin  # noqa: F401  (registers the env and policy types)
        from lerobot_subgoalvla.visualization.checkpoint import load_policy

        env_cfg = env_config(args.env_type, args.task)
        policy, preprocessor, postprocessor = load_policy(args.policy_path)
        env = make_single_env(env_cfg)
        try:
            result = rollout_traces(policy, preprocessor, postprocessor, env, env_cfg, args.seed)
        finally:
            env.close()
        plot_trace_rollout(result, args.output)
        logger.info("%d traces over %d steps -> %s", len(result.plans), len(result.states), args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main())
