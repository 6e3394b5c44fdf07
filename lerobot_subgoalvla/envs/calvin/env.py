"""``CalvinEnv``: CALVIN as a gymnasium 1.x environment, single tasks or CALVIN's five-task chains.

Two modes, chosen by ``task`` (docs/calvin.md section 4):

- ``"lh_mtlc"``: one episode is one evaluation chain. Reset puts the robot at ``EVAL_ROBOT_OBS`` and the
  scene at the chain's ``scene_obs`` (spec 4.2). ``task_description`` is CALVIN's evaluation instruction of
  the *current* subtask and switches as soon as a subtask is completed; the oracle checks only that subtask,
  between the info captured when it started and the current info (spec 4.3). Reward 1 per completed subtask,
  so LeRobot's ``avg_sum_reward`` is CALVIN's average sequence length; ``is_success`` only for 5/5, so
  ``pc_success`` is the 5-chain success rate.
- a task name (one of the 34): reset to a random start from which the task is feasible; the episode ends
  with the first success (reward 1, ``is_success``) or after ``episode_length`` steps.

Spaces (S = static image side, G = gripper image side):

| key | space | meaning |
|---|---|---|
| ``pixels/static`` | Box(0, 255, (S, S, 3), uint8) | static camera (``rgb_static``) |
| ``pixels/gripper`` | Box(0, 255, (G, G, 3), uint8) | gripper camera (``rgb_gripper``) |
| ``agent_pos`` | Box(-inf, inf, (15,), float32) | ``robot_obs`` (spec 1.4) |
| ``environment_state`` | Box(-inf, inf, (24,), float32) | ``scene_obs`` (spec 1.5) |
| action, relative | Box(-1, 1, (7,), float32) | ``rel_actions``: pos/0.02, euler/0.05, gripper (spec 1.6) |
| action, absolute | Box((-inf x6, -1), (inf x6, 1), float32) | tcp pos (m), tcp euler (rad), gripper |

The simulator is created on the first ``reset`` (never in ``__init__``), so constructing the env is cheap and
forkserver workers build their own PyBullet client.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from lerobot_subgoalvla.calvin_vocab import CALVIN_FPS, EVAL_INSTRUCTIONS, TASK_NAMES
from lerobot_subgoalvla.envs.calvin.evaluation import chains as calvin_chains
from lerobot_subgoalvla.envs.calvin.expert.start_states import sample_start_state
from lerobot_subgoalvla.envs.calvin.oracle.tasks import TaskOracle
from lerobot_subgoalvla.envs.calvin.protocol import (
    ACTION_MODES,
    CALVIN_EP_LEN,
    CHAIN_LENGTH,
    LH_MTLC,
    NEW_ROLLOUT_OPTION,
    NUM_EVAL_CHAINS,
    SCENES,
)
from lerobot_subgoalvla.envs.calvin.sim.cameras import check_renderer
from lerobot_subgoalvla.envs.calvin.sim.scene import SCENE_OBS_DIM
from lerobot_subgoalvla.envs.calvin.sim.simulation import ROBOT_OBS_DIM, CalvinSimulation

logger = logging.getLogger(__name__)

ACTION_DIM = 7


class CalvinEnv(gym.Env):
    """One CALVIN simulation as a gymnasium env (module docstring: modes and spaces).

    Args:
        task: ``"lh_mtlc"`` or one of the 34 CALVIN task names.
        scene: ``"procedural"`` or ``"calvin_A"`` ... ``"calvin_D"``.
        assets_dir: calvin_env clone for the ``calvin_*`` scenes.
        chain_start: First chain id (inclusive) a ``lh_mtlc`` reset may pick.
        chain_stop: Last chain id (exclusive). With one chain in the range every episode replays that chain,
            which is how ``CalvinEnvConfig.create_envs`` gives ``lerobot-eval`` one task_id per chain.
        episode_length: Step budget per (sub)task (CALVIN's EP_LEN = 360).
        static_size: Side of the static-camera image.
        gripper_size: Side of the gripper-camera image.
        action_mode: ``"relative"`` or ``"absolute"``.
        results_path: Append one JSON line per finished chain episode here (``chains.py`` record format).
        render_mode: Only ``"rgb_array"``.
        chains: The chains of the range by id. ``CalvinEnvConfig.create_envs`` passes them so that worker
            processes need not regenerate CALVIN's chain list; default: the official 1000 chains (spec 4.1),
            generated on first use (seconds of CPU, once per process).
        renderer: ``"tiny"`` (CPU TinyRenderer) or ``"egl"`` (OpenGL, as CALVIN's data); the EGL context is
            made with the simulator, at the first reset, so each worker process has its own.
        egl_cuda_device: With ``renderer="egl"`` on NVIDIA: the CUDA GPU whose EGL device renders (None:
            ``EGL_VISIBLE_DEVICES``, default device 0).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": CALVIN_FPS}

    def __init__(
        self,
        task: str = LH_MTLC,
        *,
        scene: str = "procedural",
        assets_dir: str | Path | None = None,
        chain_start: int = 0,
        chain_stop: int = NUM_EVAL_CHAINS,
        episode_length: int = CALVIN_EP_LEN,
        static_size: int = 200,
        gripper_size: int = 84,
        action_mode: str = "relative",
        results_path: str | Path | None = None,
        render_mode: str = "rgb_array",
        chains: Mapping[int, calvin_chains.Chain] | None = None,
        renderer: str = "tiny",
        egl_cuda_device: int | None = None,
    ) -> None:
        check_renderer(renderer)
        _check_arguments(
            task, scene, action_mode, render_mode, episode_length, chain_start, chain_stop, chains
        )
        self.task = task
        self.scene = scene
        self.assets_dir = assets_dir
        self.chain_ids = range(chain_start, chain_stop)
        self._chains = None if chains is None else {cid: chains[cid] for cid in self.chain_ids}
        self.episode_length = episode_length
        self.static_size = static_size
        self.gripper_size = gripper_size
        self.action_mode = action_mode
        self.renderer = renderer
        self.egl_cuda_device = egl_cuda_device
        self.results_path = Path(results_path) if results_path is not None else None
        self.render_mode = render_mode
        self.metadata = {"render_modes": ["rgb_array"], "render_fps": CALVIN_FPS}
        self.is_chain_mode = task == LH_MTLC
        # lerobot's rollout caps an episode at _max_episode_steps; a chain needs up to five subtask budgets.
        self._max_episode_steps = episode_length * (CHAIN_LENGTH if self.is_chain_mode else 1)
        self.observation_space = self._make_observation_space()
        self.action_space = self._make_action_space()

        self._sim: CalvinSimulation | None = None
        self._loaded_state = -1  # pybullet state id of the freshly loaded world (made with the simulator)
        self._oracle = TaskOracle()
        self._subtasks: tuple[str, ...] = () if self.is_chain_mode else (task,)
        self._chain_id: int | None = None
        self._subtask_index = 0
        self._subtask_start_info: dict[str, Any] | None = None
        self._subtask_steps = 0
        self._steps_per_subtask: list[int] = []
        self._episode_over = False
        self._last_static: np.ndarray | None = None

    def _fresh_simulation(self) -> None:
        """Build the simulator at the first reset; restore its freshly loaded state at every reset."""
        if self._sim is None:
            self._sim = CalvinSimulation(
                scene=self.scene,
                assets_dir=self.assets_dir,
                static_size=self.static_size,
                gripper_size=self.gripper_size,
                action_mode=self.action_mode,
                renderer=self.renderer,
                egl_cuda_device=self.egl_cuda_device,
            )
            # Every episode starts from the just-loaded world, as in a fresh calvin_env: pybullet keeps
            # contact caches across resets, so without this a first reset(seed) differs from later ones.
            self._loaded_state = self._sim.client.saveState()
        self._sim.client.restoreState(stateId=self._loaded_state)

    # ------------------------------------------------------------------------------------------ spaces
    def _make_observation_space(self) -> gym.spaces.Dict:
        def image(side: int) -> gym.spaces.Box:
            return gym.spaces.Box(0, 255, (side, side, 3), dtype=np.uint8)

        def vector(dim: int) -> gym.spaces.Box:
            return gym.spaces.Box(-np.inf, np.inf, (dim,), dtype=np.float32)

        return gym.spaces.Dict(
            {
                "pixels": gym.spaces.Dict(
                    {"static": image(self.static_size), "gripper": image(self.gripper_size)}
                ),
                "agent_pos": vector(ROBOT_OBS_DIM),
                "environment_state": vector(SCENE_OBS_DIM),
            }
        )

    def _make_action_space(self) -> gym.spaces.Box:
        if self.action_mode == "relative":
            return gym.spaces.Box(-1.0, 1.0, (ACTION_DIM,), dtype=np.float32)
        low = np.array([-np.inf] * 6 + [-1.0], dtype=np.float32)
        return gym.spaces.Box(low, -low, dtype=np.float32)

    # ------------------------------------------------------------------------------------------ public
    @property
    def task_description(self) -> str:
        """CALVIN's evaluation instruction (spec 4.3) of the current (sub)task.

        Before the first reset of a chain env this is the first subtask of chain ``chain_start``; after the
        fifth subtask it stays on the fifth.
        """
        return EVAL_INSTRUCTIONS[self.current_task]

    @property
    def current_task(self) -> str:
        """Name of the (sub)task the oracle is checking now."""
        subtasks = self._subtasks or self._chain(self.chain_ids[0]).tasks
        return subtasks[min(self._subtask_index, len(subtasks) - 1)]

    @property
    def simulation(self) -> CalvinSimulation:
        """The wrapped simulation (created by the first ``reset``), e.g. for scripted experts or rendering."""
        if self._sim is None:
            raise RuntimeError("CalvinEnv has no simulation before its first reset(); call env.reset() first")
        return self._sim

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Start an episode.

        Args:
            seed: Seeds ``self.np_random``, the only source of randomness (chain choice, random starts).
            options: Optional ``robot_obs`` (15,) and/or ``scene_obs`` (24,) overriding the start state,
                ``chain_id`` (``lh_mtlc`` only: which chain of the range to run). LeRobot's
                ``lerobot_new_rollout`` flag is accepted and ignored.

        Returns:
            ``(observation, info)``.

        Raises:
            ValueError: Unknown option keys, or a bad ``robot_obs`` / ``scene_obs`` / ``chain_id``.
        """
        super().reset(seed=seed)
        options = dict(options or {})
        allowed = {"robot_obs", "scene_obs", NEW_ROLLOUT_OPTION} | (
            {"chain_id"} if self.is_chain_mode else set()
        )
        if unknown := sorted(set(options) - allowed):
            raise ValueError(
                f"Unknown CalvinEnv reset option(s) {unknown}; valid: {', '.join(sorted(allowed))}"
            )
        robot_obs = _checked_state(options.get("robot_obs"), ROBOT_OBS_DIM, "robot_obs")
        scene_obs = _checked_state(options.get("scene_obs"), SCENE_OBS_DIM, "scene_obs")
        self._fresh_simulation()
        # CALVIN keeps the previous episode's gripper command across resets (spec 3.8), so robot_obs[14] of
        # the first frame would depend on episode order. Reset it to the start state's (open unless robot_obs
        # says otherwise): the same seed then gives the same episode, and chain shards are order-independent.
        self._sim.robot.gripper_action = 1 if robot_obs is None or robot_obs[14] > 0 else -1
        if self.is_chain_mode:
            self._chain_id = self._pick_chain(options.get("chain_id"))
            chain = self._chain(self._chain_id)
            self._subtasks = tuple(chain.tasks)
            robot_obs = calvin_chains.EVAL_ROBOT_OBS if robot_obs is None else robot_obs
            scene_obs = chain.scene_obs if scene_obs is None else scene_obs
            logger.debug("chain %d: %s", self._chain_id, ", ".join(chain.tasks))
            self._sim.reset(robot_obs=robot_obs, scene_obs=scene_obs, np_random=self.np_random)
        elif robot_obs is None and scene_obs is None:
            sample_start_state(self.task, self._sim, self.np_random)
        else:
            self._sim.reset(robot_obs=robot_obs, scene_obs=scene_obs, np_random=self.np_random)
        self._subtask_index = 0
        self._subtask_steps = 0
        self._steps_per_subtask = []
        self._episode_over = False
        self._subtask_start_info = self._sim.get_info()
        return self._observation(), self._info(success=False)

    def step(self, action: np.ndarray) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        """Apply one 30 Hz action and score the current (sub)task with the oracle.

        Raises:
            ValueError: If ``action`` is not 7 finite numbers.
            RuntimeError: If called before ``reset`` or after the episode ended.
        """
        if self._sim is None or self._subtask_start_info is None:
            raise RuntimeError("CalvinEnv.step() called before reset(); call env.reset() first")
        if self._episode_over:
            raise RuntimeError("CalvinEnv.step() called after the episode ended; call env.reset() first")
        self._sim.step(action)  # validates: ValueError unless 7 finite numbers
        self._subtask_steps += 1
        end_info = self._sim.get_info()
        reward, terminated, truncated = 0.0, False, False
        if self._oracle.is_completed(self.current_task, self._subtask_start_info, end_info):
            reward = 1.0
            self._steps_per_subtask.append(self._subtask_steps)
            self._subtask_index += 1
            self._subtask_steps = 0
            self._subtask_start_info = end_info  # the next subtask starts from here, no reset (spec 4.3)
            terminated = self._subtask_index == len(self._subtasks)
        elif self._subtask_steps >= self.episode_length:
            truncated = True  # this (sub)task ran out of its budget: the episode (chain) ends here
            self._steps_per_subtask.append(self._subtask_steps)
        self._episode_over = terminated or truncated
        if self._episode_over:
            self._write_result()
        return self._observation(), reward, terminated, truncated, self._info(success=terminated)

    def render(self) -> np.ndarray:
        """The latest static-camera frame, HWC uint8 (what ``lerobot-eval`` writes to its videos)."""
        if self._last_static is None:
            raise RuntimeError("CalvinEnv.render() called before reset(); call env.reset() first")
        return self._last_static.copy()

    def close(self) -> None:
        """Disconnect the PyBullet client; a later ``reset`` creates a new one."""
        if self._sim is not None:
            self._sim.close()
            self._sim = None

    # ------------------------------------------------------------------------------------------ helpers
    def _chain(self, chain_id: int) -> calvin_chains.Chain:
        return official_chains()[chain_id] if self._chains is None else self._chains[chain_id]

    def _pick_chain(self, requested: Any) -> int:
        if requested is None:
            return int(self.np_random.integers(self.chain_ids.start, self.chain_ids.stop))
        if not isinstance(requested, int | np.integer) or int(requested) not in self.chain_ids:
            raise ValueError(
                f"reset option chain_id={requested!r} is not in this env's chain range "
                f"[{self.chain_ids.start}, {self.chain_ids.stop})"
            )
        return int(requested)

    def _observation(self) -> dict[str, Any]:
        cameras = self.simulation.render_cameras()
        self._last_static = cameras["static"]
        return {
            "pixels": {"static": cameras["static"], "gripper": cameras["gripper"]},
            "agent_pos": self.simulation.robot_obs().astype(np.float32),
            "environment_state": self.simulation.scene_obs().astype(np.float32),
        }

    def _info(self, success: bool) -> dict[str, Any]:
        info = {"is_success": bool(success), "num_completed": self._subtask_index}
        if self.is_chain_mode:
            info["subtask_index"] = min(self._subtask_index, CHAIN_LENGTH - 1)
            info["chain_id"] = self._chain_id
        return info

    def _write_result(self) -> None:
        if self.results_path is None or not self.is_chain_mode:
            return
        record = calvin_chains.EpisodeResult(
            chain_id=self._chain_id,
            tasks=self._subtasks,
            num_completed=self._subtask_index,
            subtask_steps=tuple(self._steps_per_subtask),
        )
        calvin_chains.append_episode_result(self.results_path, record)


def _check_arguments(
    task: str,
    scene: str,
    action_mode: str,
    render_mode: str,
    episode_length: int,
    chain_start: int,
    chain_stop: int,
    chains: Mapping[int, calvin_chains.Chain] | None,
) -> None:
    """Reject bad ``CalvinEnv`` arguments with one line naming the value and what is allowed."""
    if task != LH_MTLC and task not in TASK_NAMES:
        raise ValueError(f"Unknown CALVIN env task {task!r}; valid: {LH_MTLC!r}, {', '.join(TASK_NAMES)}")
    if scene not in SCENES:
        raise ValueError(f"Unknown CALVIN scene {scene!r}; valid: {', '.join(SCENES)}")
    if action_mode not in ACTION_MODES:
        raise ValueError(f"Unknown action_mode {action_mode!r}; valid: {', '.join(ACTION_MODES)}")
    if render_mode != "rgb_array":
        raise ValueError(f"Unknown render_mode {render_mode!r}; CalvinEnv renders only 'rgb_array'")
    max_stop = NUM_EVAL_CHAINS if chains is None else max(chains, default=-1) + 1
    if task == LH_MTLC and not 0 <= chain_start < chain_stop <= max_stop:
        raise ValueError(
            f"Chain range [{chain_start}, {chain_stop}) is not valid; need 0 <= start < stop <= {max_stop}"
        )
    if episode_length < 1:
        raise ValueError(f"episode_length={episode_length} must be >= 1")
    if chains is not None and set(range(chain_start, chain_stop)) - set(chains):
        missing = sorted(set(range(chain_start, chain_stop)) - set(chains))[:5]
        raise ValueError(f"chains lacks ids {missing} of the range [{chain_start}, {chain_stop})")


@functools.cache
def official_chains() -> tuple[calvin_chains.Chain, ...]:
    """CALVIN's 1000 evaluation chains (spec 4.1), generated once per process."""
    return tuple(calvin_chains.generate_chains(NUM_EVAL_CHAINS))


def _checked_state(value: Any, dim: int, name: str) -> np.ndarray | None:
    """Validate a ``reset`` option vector: shape ``(dim,)`` and finite, else a ValueError naming it."""
    if value is None:
        return None
    array = np.asarray(value, dtype=np.float64)
    if array.shape != (dim,):
        raise ValueError(f"reset option {name} must have shape ({dim},), got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"reset option {name} contains NaN or inf: {array.tolist()}")
    return array
