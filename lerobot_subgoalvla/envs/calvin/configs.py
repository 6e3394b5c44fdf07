"""``--env.type=calvin``: CALVIN as a LeRobot 0.6 environment.

``CalvinEnvConfig.create_envs`` returns ``{"calvin": {task_id: VectorEnv}}``. In the long-horizon mode
(``task="lh_mtlc"``, CALVIN's evaluation protocol, docs/calvin.md section 4) there is one ``task_id`` per
chain,
equal to the chain id, so ``lerobot-eval --eval.n_episodes=1`` runs every chain of ``[chain_start,
chain_stop)`` exactly once; disjoint chain ranges shard an evaluation across processes or machines. In the
single-task mode (``task=<one of the 34 task names>``) there is one ``task_id``, the task's CALVIN id, and
each episode starts from a random valid state drawn from the episode's seed.

All task_ids share the simulators: each task_id is a view (``vector.TaskView``) on one lazily built vector env
per evaluating thread (``vector.SharedVectorEnvs``); a chain's view pins its ``chain_id`` into every
``reset``. ``lerobot-eval`` builds all 1000 task_ids up front and evaluates them one after the other (or
``max_parallel_tasks`` at a time, one thread each), so one set of simulators (and, with async envs, one pool
of worker processes) per thread serves all chains, instead of 1000 of them being started, or kept alive.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig

from lerobot_subgoalvla.calvin_vocab import CALVIN_FPS, TASK_NAMES
from lerobot_subgoalvla.config_error import ConfigError
from lerobot_subgoalvla.contract.calvin import GRIPPER_CAMERA_KEY, STATIC_CAMERA_KEY
from lerobot_subgoalvla.contract.keys import ACTION_KEY as ACTION
from lerobot_subgoalvla.contract.keys import ENV_STATE_KEY, STATE_KEY
from lerobot_subgoalvla.envs.calvin.protocol import (
    ACTION_MODES,
    CALVIN_EP_LEN,
    LH_MTLC,
    NUM_EVAL_CHAINS,
    RENDERERS,
    SCENES,
)
from lerobot_subgoalvla.envs.calvin.vector import SharedVectorEnvs, TaskView, make_frozen_env


def _default_features() -> dict[str, PolicyFeature]:
    return {
        ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(7,)),
        "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(15,)),
        "environment_state": PolicyFeature(type=FeatureType.ENV, shape=(24,)),
        "pixels/static": PolicyFeature(type=FeatureType.VISUAL, shape=(200, 200, 3)),
        "pixels/gripper": PolicyFeature(type=FeatureType.VISUAL, shape=(84, 84, 3)),
    }


def _default_features_map() -> dict[str, str]:
    # Must agree with lerobot's preprocess_observation, which renames at run time: `pixels/<name>` becomes
    # `observation.images.<name>`, `agent_pos` the state (it ignores this map).
    return {
        ACTION: ACTION,
        "agent_pos": STATE_KEY,
        "environment_state": ENV_STATE_KEY,
        "pixels/static": STATIC_CAMERA_KEY,
        "pixels/gripper": GRIPPER_CAMERA_KEY,
    }


@EnvConfig.register_subclass("calvin")
@dataclass
class CalvinEnvConfig(EnvConfig):
    """CALVIN env options (``--env.<field>=...``).

    Each field's help is the comment above it: ``--help`` shows it.
    """

    # `"lh_mtlc"` (chains of five subtasks, CALVIN's benchmark) or one of the 34 task names.
    task: str | None = LH_MTLC
    # Control frequency; CALVIN steps at 30 Hz (240 Hz physics, 8 substeps), so only 30 is valid.
    fps: int = CALVIN_FPS
    # `"procedural"` (our generated desk, no files needed) or `"calvin_A"` ... `"calvin_D"` (CALVIN's own
    # URDFs, read from `assets_dir`).
    scene: str = "procedural"
    # A clone of calvin_env (with `data/` and `conf/`); required for the `calvin_*` scenes.
    assets_dir: str | None = None
    # First chain id evaluated in `lh_mtlc` (inclusive).
    chain_start: int = 0
    # Last chain id evaluated in `lh_mtlc` (exclusive); at most 1000.
    chain_stop: int = NUM_EVAL_CHAINS
    # Step budget of one (sub)task; CALVIN's EP_LEN is 360 (12 s). A chain episode lasts at most `5 *
    # episode_length` steps.
    episode_length: int = CALVIN_EP_LEN
    # Side of the square static-camera image (CALVIN: 200).
    static_image_size: int = 200
    # Side of the square gripper-camera image (CALVIN: 84).
    gripper_image_size: int = 84
    # `"relative"` (CALVIN's normalised rel_actions, Box(-1, 1)) or `"absolute"` (tcp position, euler angles,
    # gripper).
    action_mode: str = "relative"
    # `"tiny"` (pybullet's CPU TinyRenderer, default) or `"egl"` (OpenGL through pybullet's EGL plugin: how
    # CALVIN rendered its dataset; a model trained on real CALVIN sees such images).
    renderer: str = "tiny"
    # With `--env.renderer=egl` on NVIDIA GPUs: CUDA devices to render on, e.g. `[0,1]`; eval worker i
    # renders on the EGL device of CUDA device `i mod len` (calvin_env's mapping). Unset: EGL_VISIBLE_DEVICES
    # (device 0).
    egl_cuda_devices: list[int] | None = None
    # If set, every finished chain episode appends one JSON line (chains.py's record) here; `subgoalvla-
    # calvin-report` turns them into CALVIN's LH-1..5 table.
    results_path: str | None = None
    # Continue an evaluation that was stopped: chains of the range already in `results_path` are skipped
    # and the others appended. Without it, a `results_path` that holds chains of the range is refused (they
    # would be counted twice, or mixed with another policy's).
    resume: bool = False
    # the env's observation/action features (set from the image sizes; leave unset).
    features: dict[str, PolicyFeature] = field(default_factory=_default_features)
    # env key -> LeRobot key (`agent_pos` -> `observation.state`, ...; leave unset).
    features_map: dict[str, str] = field(default_factory=_default_features_map)
    # LeRobot's: task_ids evaluated at once, one thread and one set of simulators each.
    max_parallel_tasks: int = 1
    # LeRobot's: skip gymnasium's env checker (CalvinEnv passes it; the check costs a reset).
    disable_env_checker: bool = True

    def __post_init__(self) -> None:
        self._validate()
        self.features["pixels/static"] = PolicyFeature(
            type=FeatureType.VISUAL, shape=(self.static_image_size, self.static_image_size, 3)
        )
        self.features["pixels/gripper"] = PolicyFeature(
            type=FeatureType.VISUAL, shape=(self.gripper_image_size, self.gripper_image_size, 3)
        )

    def _validate(self) -> None:
        if self.task != LH_MTLC and self.task not in TASK_NAMES:
            raise ConfigError(
                f"--env.task={self.task!r} is not valid; use {LH_MTLC!r} or one of: {', '.join(TASK_NAMES)}"
            )
        if self.scene not in SCENES:
            raise ConfigError(f"--env.scene={self.scene!r} is not valid; use one of: {', '.join(SCENES)}")
        if self.scene != "procedural" and self.assets_dir is None:
            raise ConfigError(
                f"--env.scene={self.scene} needs --env.assets_dir=<a clone of calvin_env with data/ and "
                "conf/>"
            )
        if self.action_mode not in ACTION_MODES:
            raise ConfigError(
                f"--env.action_mode={self.action_mode!r} is not valid; use one of: {', '.join(ACTION_MODES)}"
            )
        if self.egl_cuda_devices is not None and (
            self.renderer != "egl" or not self.egl_cuda_devices or min(self.egl_cuda_devices) < 0
        ):
            raise ConfigError(
                f"--env.egl_cuda_devices={self.egl_cuda_devices} needs --env.renderer=egl and a non-empty "
                "list of CUDA indices >= 0, e.g. [0,1]"
            )
        if self.renderer not in RENDERERS:
            raise ConfigError(
                f"--env.renderer={self.renderer!r} is not valid; use one of: {', '.join(RENDERERS)}"
            )
        if self.fps != CALVIN_FPS:
            raise ConfigError(f"--env.fps={self.fps} is not valid; CALVIN steps at {CALVIN_FPS} Hz")
        if not 0 <= self.chain_start < self.chain_stop <= NUM_EVAL_CHAINS:
            raise ConfigError(
                f"--env.chain_start={self.chain_start} / --env.chain_stop={self.chain_stop} must satisfy "
                f"0 <= chain_start < chain_stop <= {NUM_EVAL_CHAINS}"
            )
        for name in ("episode_length", "static_image_size", "gripper_image_size"):
            if getattr(self, name) < 1:
                raise ConfigError(f"--env.{name}={getattr(self, name)} must be a positive integer")
        self._validate_paths()

    def _validate_paths(self) -> None:
        """Files are checked now, not after the policy has loaded or the rollout has run."""
        if self.scene != "procedural":
            from lerobot_subgoalvla.envs.calvin.sim.assets import load_scene_source  # light: yaml + paths

            try:
                load_scene_source(self.scene, self.assets_dir)
            except (FileNotFoundError, ValueError) as error:
                raise ConfigError(f"--env.assets_dir: {error}") from None
        if self.results_path is not None:
            folder = Path(self.results_path).expanduser().resolve().parent
            existing = next((p for p in (folder, *folder.parents) if p.exists()), None)
            if existing is None or not existing.is_dir() or not os.access(existing, os.W_OK):
                raise ConfigError(
                    f"--env.results_path={self.results_path}: cannot write there (nearest existing folder "
                    f"{existing} is not a writable directory); choose a writable path"
                )
        if self.task == LH_MTLC:
            self.pending_chain_ids()  # a results file that holds chains of the range is refused now

    @property
    def chain_ids(self) -> range:
        """The chain ids of the range (``lh_mtlc`` only)."""
        return range(self.chain_start, self.chain_stop)

    def pending_chain_ids(self) -> list[int]:
        """The chain ids still to evaluate: the range, less those already in ``results_path`` when resuming.

        Raises:
            ConfigError: ``results_path`` holds chains of the range without ``resume``, it holds all of
                them (nothing to do), or it is not a results file.
        """
        if self.results_path is None or not Path(self.results_path).expanduser().exists():
            return list(self.chain_ids)
        from lerobot_subgoalvla.envs.calvin.evaluation.results import records_to_resume  # light: json

        try:
            done = {r.chain_id for r in records_to_resume(Path(self.results_path).expanduser())}
        except (ValueError, OSError) as error:
            raise ConfigError(f"--env.results_path: {error}") from None
        pending = [cid for cid in self.chain_ids if cid not in done]
        flag = f"--env.results_path={self.results_path}"
        if not self.resume and len(pending) < len(self.chain_ids):
            raise ConfigError(
                f"{flag} already holds {len(self.chain_ids) - len(pending)} chain(s) of "
                f"[{self.chain_start}, {self.chain_stop}); pass --env.resume=true to evaluate only the "
                "others, or choose a new --env.results_path"
            )
        if not pending:
            raise ConfigError(
                f"{flag} already holds every chain of [{self.chain_start}, {self.chain_stop}); nothing to "
                f"evaluate - run subgoalvla-calvin-report {self.results_path}"
            )
        return pending

    @property
    def gym_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of ``CalvinEnv``; ``create_envs`` adds the chain range and its chains
        (``lh_mtlc``)."""
        return {
            "task": self.task,
            "scene": self.scene,
            "assets_dir": self.assets_dir,
            "episode_length": self.episode_length,
            "static_size": self.static_image_size,
            "gripper_size": self.gripper_image_size,
            "action_mode": self.action_mode,
            "renderer": self.renderer,
            "results_path": self.results_path,
        }

    def create_envs(self, n_envs: int, use_async_envs: bool = False) -> dict[str, dict[int, Any]]:
        """Build ``{"calvin": {chain_id: vector env}}`` for ``lh_mtlc``, ``{"calvin_<task>": {task_id: ...}}``
        for one task: the group name in ``eval_info.json`` then says which was evaluated (a single-task result
        must never pass for a chain in ``subgoalvla-calvin-report``).

        Args:
            n_envs: Sub-envs per vector env (``--eval.batch_size``).
            use_async_envs: One forkserver worker process per sub-env (when ``n_envs > 1``).

        Returns:
            One view per chain id (``lh_mtlc``) or one for the task's CALVIN id, all sharing the simulators.
        """
        if n_envs < 1:
            raise ValueError(f"--eval.batch_size must be >= 1 for the calvin env, got {n_envs}")
        from lerobot_subgoalvla.envs.calvin.env import CalvinEnv, official_chains  # imports the simulator

        kwargs: dict[str, Any] = dict(self.gym_kwargs)
        if self.task == LH_MTLC:
            chains = official_chains()  # once here, not in every worker process
            kwargs.update(
                chain_start=self.chain_start,
                chain_stop=self.chain_stop,
                chains={cid: chains[cid] for cid in self.chain_ids},
            )
            pinned = {cid: {"chain_id": cid} for cid in self.pending_chain_ids()}
        else:
            pinned = {TASK_NAMES.index(self.task): {}}
        probe = CalvinEnv(**kwargs)  # cheap: the simulator is created on the first reset
        spaces = (probe.observation_space, probe.action_space, dict(probe.metadata))
        probe.close()
        devices = self.egl_cuda_devices or [None]
        env_fns = [
            partial(make_frozen_env, **kwargs, egl_cuda_device=devices[i % len(devices)])
            for i in range(n_envs)
        ]
        shared = SharedVectorEnvs(env_fns, use_async_envs and n_envs > 1)
        suite = self.type if self.task == LH_MTLC else f"{self.type}_{self.task}"
        return {suite: {task_id: TaskView(shared, options, *spaces) for task_id, options in pinned.items()}}
