"""Vector envs for ``lerobot-eval``: one set of simulators per thread, shared by every task_id's view.

``CalvinEnvConfig.create_envs`` (``configs.py``) gives ``lerobot-eval`` one ``TaskView`` per task_id; all
views use one lazily built ``SharedVectorEnvs``. Sub-envs are ``FrozenAfterEpisodeEnd(CalvinEnv(...))``. This
module
imports gymnasium only: it is what a forkserver worker process imports to build its env.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import gymnasium as gym
from gymnasium.vector.utils import batch_space

from lerobot_subgoalvla.envs.calvin.protocol import NEW_ROLLOUT_OPTION


class FrozenAfterEpisodeEnd(gym.Wrapper):
    """Stops simulating a sub-env once its episode ended, until the next rollout starts.

    ``lerobot-eval``'s rollout steps the whole batch until every sub-env is done, and gymnasium's
    ``NEXT_STEP`` autoreset would start a finished sub-env on a new episode nobody reads. After termination or
    truncation this wrapper answers every ``step`` with the final transition (reward 0, so padded sums stay
    right) and an autoreset with the final observation; only a ``reset`` whose options carry
    ``NEW_ROLLOUT_OPTION`` (sent by LeRobot at the start of each rollout) runs the env again. The behaviour of
    LeRobot's ``FreezeAfterEpisodeEnd``, in a module that does not import LeRobot: a worker process that
    imported
    ``lerobot.envs.utils`` would load torch and transformers (about 10 s) for nothing.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self._final: tuple | None = None

    @property
    def is_frozen(self) -> bool:
        """True between the end of an episode and the next rollout's reset."""
        return self._final is not None

    def reset(self, *, seed: Any = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        if self._final is not None and not (options or {}).get(NEW_ROLLOUT_OPTION):
            observation, _, _, _, info = self._final
            return observation, info
        self._final = None
        return self.env.reset(seed=seed, options=options)

    def step(self, action: Any) -> tuple:
        if self._final is not None:
            return self._final
        observation, reward, terminated, truncated, info = self.env.step(action)
        if terminated or truncated:
            self._final = (observation, 0.0, terminated, truncated, info)
        return observation, reward, terminated, truncated, info


def make_frozen_env(**kwargs: Any) -> gym.Env:
    """A ``CalvinEnv(**kwargs)`` wrapped in ``FrozenAfterEpisodeEnd``.

    Module-level so that ``functools.partial(make_frozen_env, ...)`` pickles with the standard pickle, as
    forkserver workers need.
    """
    from lerobot_subgoalvla.envs.calvin.env import CalvinEnv

    return FrozenAfterEpisodeEnd(CalvinEnv(**kwargs))


class SharedVectorEnvs:
    """One Sync/AsyncVectorEnv per calling thread, built on first use and shared by all task_id views.

    ``lerobot-eval`` runs task_ids sequentially in one thread, or ``max_parallel_tasks`` at a time in a thread
    pool; keying by thread gives each concurrently evaluated task its own simulators. Autoreset is
    ``NEXT_STEP`` with ``FrozenAfterEpisodeEnd`` sub-envs, as LeRobot recommends.
    """

    def __init__(self, env_fns: list[Callable[[], gym.Env]], use_async: bool) -> None:
        self.env_fns = env_fns
        self.use_async = use_async
        self._envs: dict[int, gym.vector.VectorEnv] = {}
        self._lock = threading.Lock()

    @property
    def num_alive(self) -> int:
        """How many vector envs (sets of simulators or worker pools) exist now."""
        return len(self._envs)

    def get(self) -> gym.vector.VectorEnv:
        """The calling thread's vector env (built now if it has none)."""
        key = threading.get_ident()
        with self._lock:
            if key not in self._envs:
                mode = gym.vector.AutoresetMode.NEXT_STEP
                if self.use_async:
                    self._envs[key] = gym.vector.AsyncVectorEnv(
                        self.env_fns, context="forkserver", autoreset_mode=mode
                    )
                else:
                    self._envs[key] = gym.vector.SyncVectorEnv(self.env_fns, autoreset_mode=mode)
            return self._envs[key]

    def close(self) -> None:
        """Close every vector env; a later use builds a new one."""
        with self._lock:
            envs, self._envs = list(self._envs.values()), {}
        for env in envs:
            env.close()


class TaskView:
    """The vector env of one task_id: the shared simulators, with this task's options pinned into ``reset``.

    Quacks like the ``VectorEnv`` that ``lerobot-eval``'s rollout uses (``num_envs``, spaces, ``metadata``,
    ``unwrapped``, ``reset``, ``step``, ``call``, ``get_attr``, ``render``, ``close``).
    """

    def __init__(
        self,
        shared: SharedVectorEnvs,
        reset_options: dict[str, Any],
        single_observation_space: gym.Space,
        single_action_space: gym.Space,
        metadata: dict[str, Any],
    ) -> None:
        self._shared = shared
        self._reset_options = reset_options
        self.num_envs = len(shared.env_fns)
        self.single_observation_space = single_observation_space
        self.single_action_space = single_action_space
        self.observation_space = batch_space(single_observation_space, self.num_envs)
        self.action_space = batch_space(single_action_space, self.num_envs)
        self.metadata = metadata

    @property
    def unwrapped(self) -> TaskView:
        return self

    def reset(self, *, seed: Any = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        return self._shared.get().reset(seed=seed, options={**(options or {}), **self._reset_options})

    def step(self, actions: Any) -> tuple:
        return self._shared.get().step(actions)

    def call(self, name: str, *args: Any, **kwargs: Any) -> tuple:
        return self._shared.get().call(name, *args, **kwargs)

    def get_attr(self, name: str) -> tuple:
        return self._shared.get().get_attr(name)

    def render(self) -> tuple:
        return self._shared.get().render()

    def close(self) -> None:
        """Close the shared vector envs (``close_envs`` closes every view; later use rebuilds them)."""
        self._shared.close()
