"""One Meta-World expert episode, recorded through LeRobot's own Meta-World gym env, as dataset frames.

The env is the one ``lerobot-eval --env.type=metaworld`` steps: ``lerobot.envs.make_env(MetaworldEnv(task))``
(LeRobot's public API) builds it, and we step its single gym env (``vector_env.envs[0]``), so each recorded
image and state is byte for byte what a policy receives at evaluation: LeRobot's repositioned ``corner2``
camera, its 180-degree flip, ``agent_pos`` = Meta-World obs[:4] (hand x, y, z and gripper opening). The
expert acts on Meta-World's full 39-dim observation, which LeRobot's env does not hand out; we read it where
the underlying Meta-World env returns it (a tap on its ``step``/``reset``), because calling Meta-World's
``_get_obs`` again would advance its frame stack and change the next observation.

An episode ends at Meta-World's first ``info["success"]``, with that step's frame included, or after
``max_steps`` (the env's 500 at most). LeRobot's env ends the episode at the first success and resets the
scene inside that same ``step``, so it cannot run on past success; ``lerobot-eval`` stops there too.

Dimension legend:
    T   frames of one episode (one per env step)
    S   rendered image side (480 unless ``image_size`` is given)
"""

from __future__ import annotations

import contextlib
import gc
import io
import logging
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lerobot_subgoalvla.contract.keys import ACTION_KEY, ENV_STATE_KEY, SINGLE_IMAGE_KEY, STATE_KEY
from lerobot_subgoalvla.metaworld.tasks import expert_policy, task_description, task_id

logger = logging.getLogger(__name__)

#: LeRobot's Meta-World env renders 480 x 480 (Meta-World's default) whatever its config says.
LEROBOT_IMAGE_SIZE = 480
#: The published dataset's and LeRobot's env's frame rate.
METAWORLD_FPS = 80


@dataclass
class Episode:
    """One recorded episode.

    Attributes:
        task: Meta-World task name (``drawer-open-v3``).
        seed: the env seed of the episode (its start state).
        success: whether Meta-World reported success before ``max_steps``.
        frames: ``{feature key: (T, ...) array}`` in the dataset's dtypes (``features()`` in generate.py).
        seconds: time spent in ``render``, ``physics`` (Meta-World step and reset), ``expert`` and ``env``
            (everything else in the loop: LeRobot's wrapper, copies).
    """

    task: str
    seed: int
    success: bool
    frames: dict[str, np.ndarray]
    seconds: dict[str, float] = field(default_factory=dict)

    @property
    def length(self) -> int:
        """Number of frames T."""
        return len(self.frames["action"])


class MetaworldRecorder:
    """LeRobot's Meta-World env for one task plus Meta-World's expert; ``record`` plays one episode.

    Args:
        task: Meta-World task name, e.g. ``reach-v3``.
        image_size: rendered side S; 480 is what LeRobot's env (and so ``lerobot-eval``) renders.
    """

    def __init__(self, task: str, image_size: int = LEROBOT_IMAGE_SIZE) -> None:
        from lerobot.envs.configs import MetaworldEnv
        from lerobot.envs.factory import make_env

        self.task = task
        self.description = task_description(task)
        self.task_id = task_id(task)
        # make_env prints its progress; keep it out of the command's output (the log says what runs).
        with contextlib.redirect_stdout(io.StringIO()) as printed:
            self._vector_env = make_env(MetaworldEnv(task=task), n_envs=1)[task][0]
        logger.debug("%s", printed.getvalue().strip())
        self.env = self._vector_env.envs[0]
        self.max_episode_steps = int(self.env._max_episode_steps)  # what lerobot-eval runs at most
        self.expert = expert_policy(task)
        self.seconds = {"render": 0.0, "physics": 0.0}
        self._full_obs: np.ndarray | None = None
        # LeRobot creates the Meta-World env lazily (at the first reset, in its worker); create it now so the
        # taps and the render size are in place before anything is rendered.
        self.env._ensure_env()
        self._tap(self.env._env, image_size)

    def _tap(self, inner: Any, image_size: int) -> None:
        """Keep Meta-World's full observation and time physics and rendering, without changing either."""

        def timed(name: str, method: Callable, keep_obs: bool) -> Callable:
            def wrapper(*args: Any, **kwargs: Any) -> Any:
                start = time.perf_counter()
                out = method(*args, **kwargs)
                self.seconds[name] += time.perf_counter() - start
                if keep_obs:
                    self._full_obs = np.asarray(out[0], dtype=np.float64).copy()  # (39,)
                return out

            return wrapper

        inner.step = timed("physics", inner.step, keep_obs=True)
        inner.reset = timed("physics", inner.reset, keep_obs=True)
        inner.render = timed("render", inner.render, keep_obs=False)
        if image_size != LEROBOT_IMAGE_SIZE:  # the offscreen buffer is allocated at the first render
            inner.mujoco_renderer.width = inner.mujoco_renderer.height = image_size

    def record(
        self, seed: int, max_steps: int | None = None, action_noise: float = 0.0, rng: Any = None
    ) -> Episode:
        """Play one expert episode from the start state of ``seed``.

        Args:
            seed: env seed (Meta-World randomises object and goal positions from it).
            max_steps: step cap (default and upper bound: the env's 500).
            action_noise: std of Gaussian noise added to the executed action (the label stays the expert's).
            rng: ``numpy.random.Generator`` for the noise (needed when ``action_noise > 0``).

        Returns:
            The episode, successful or not.
        """
        limit = min(max_steps or self.max_episode_steps, self.max_episode_steps)
        self.seconds = {"render": 0.0, "physics": 0.0}
        expert_seconds, start = 0.0, time.perf_counter()
        rows: dict[str, list] = {
            key: [] for key in ("image", "state", "env_state", "action", "reward", "done")
        }
        obs, _ = self.env.reset(seed=seed)
        success = False
        for _ in range(limit):
            full_obs = self._full_obs
            tick = time.perf_counter()
            with warnings.catch_warnings():
                # Meta-World's experts warn whenever a gain exceeds the action bounds; the env clips anyway.
                warnings.simplefilter("ignore", UserWarning)
                label = np.clip(self.expert.get_action(full_obs), -1.0, 1.0).astype(np.float32)  # (4,)
            expert_seconds += time.perf_counter() - tick
            executed = label
            if action_noise > 0:
                executed = np.clip(label + rng.normal(0.0, action_noise, 4), -1.0, 1.0).astype(np.float32)
            next_obs, reward, _, truncated, info = self.env.step(executed)
            success = bool(info.get("success", False))
            for key, value in zip(
                rows, (obs["pixels"], obs["agent_pos"], full_obs, label, reward, success), strict=True
            ):
                rows[key].append(value)
            if success or truncated:
                break
            obs = next_obs
        seconds = {**self.seconds, "expert": expert_seconds}
        seconds["env"] = max(0.0, time.perf_counter() - start - sum(seconds.values()))
        return Episode(self.task, seed, success, self._frames(rows), seconds)

    def _frames(self, rows: dict[str, list]) -> dict[str, np.ndarray]:
        """Per-step lists -> ``{feature key: (T, ...) array}`` in the published dataset's dtypes."""
        length = len(rows["action"])
        return {
            SINGLE_IMAGE_KEY: np.stack(rows["image"]).astype(np.uint8),  # (T, S, S, 3)
            STATE_KEY: np.stack(rows["state"]).astype(np.float32),  # (T, 4)
            ENV_STATE_KEY: np.stack(rows["env_state"]).astype(np.float32),  # (T, 39)
            ACTION_KEY: np.stack(rows["action"]),  # (T, 4)
            "next.reward": np.asarray(rows["reward"], dtype=np.float32)[:, None],  # (T, 1)
            "next.success": np.asarray(rows["done"], dtype=bool)[:, None],  # (T, 1)
            "task_id": np.full((length, 1), self.task_id, dtype=np.int16),  # (T, 1)
        }

    def close(self) -> None:
        """Free the env's EGL context now: freed later, at interpreter exit, it prints tracebacks."""
        self._vector_env.close()
        self.env = self._vector_env = self.expert = None
        gc.collect()

    def __enter__(self) -> MetaworldRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
