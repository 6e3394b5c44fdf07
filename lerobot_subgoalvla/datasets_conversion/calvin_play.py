"""Record one play segment in our CALVIN simulation with the scripted expert (used by generate_calvin.py).

CALVIN's data is *play*: an operator chains tasks from whatever state the scene is in, every frame is
recorded, and language windows are labelled afterwards where a task fired (spec 1.1, 1.7). A segment here
is the same: start from a random state in which a random task is feasible (``sample_start_state``), then
repeatedly pick a random task that is feasible *now* (``is_feasible``), run ``ScriptedExpert`` until it is
done (at most ``max_steps_per_task`` steps), and let the oracle (``TaskOracle.is_completed`` on the info
dicts at the task's first and last frame) decide whether the task really fired; only then does the span
become a language window, labelled with one of CALVIN's training annotations of that task
(``calvin_vocab.TRAINING_ANNOTATIONS``). Failed attempts stay in the segment as unlabelled play; when no task
is feasible afterwards (e.g. a missed grasp, or a fixture script that pushed with closed fingers), a short
recorded release-and-lift motion is played before the next task is drawn.

Where a window starts (``windows_from_completion``): by default at the frame the expert starts the task,
i.e. after the previous task's whole script (its release and retreat after the oracle fired) and any
release-and-lift motion. A CALVIN chain hands over to the next subtask at the *first* step its oracle fires
(spec 4.3), with the fingers still closed at the fixture, so such start states never begin a default window
(issue 25; docs/data.md). With ``windows_from_completion`` a window that follows a confirmed task starts at
the frame where that task's oracle first fired: the previous task's tail becomes the start of the next task's
demonstration, as a chain would hand it over. After a failed attempt (a chain would have ended) the window
starts where the expert starts the task, as by default.

Per frame t (spec 1.6): ``robot_obs[t]``, ``scene_obs[t]``, the camera images of state t, ``actions[t]`` =
[TCP position and euler of state t+1, the gripper command of step t] and ``rel_actions[t]`` derived from
``actions[t]`` and ``robot_obs[t]`` exactly as CALVIN's renderer does. Like CALVIN, the state after the last
action is not saved. Depth and tactile sensors are not rendered (the generated-data profile has the 6
``calvin_format.CORE_KEYS``).

The simulator is imported inside the functions: ``datasets_conversion`` does not depend on ``envs`` at import.

Dimension legend:
    F   frames of the segment
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from lerobot_subgoalvla.calvin_vocab import TASK_NAMES, TRAINING_ANNOTATIONS

logger = logging.getLogger(__name__)

POS_SCALE, ORN_SCALE = 0.02, 0.05  # spec 1.6: rel = clip(delta, -scale, scale) / scale
#: Recorded "release and lift" motion when no task is feasible (gripper open, TCP up 1 cm per step).
RECOVERY_ACTION = np.array([0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0])
RECOVERY_STEPS = 10


def relative_actions(actions: np.ndarray, robot_obs: np.ndarray) -> np.ndarray:
    """CALVIN's ``rel_actions`` (spec 1.6) from absolute ``actions`` (F, 7) and ``robot_obs`` (F, 15)."""
    d_pos = np.clip(actions[:, :3] - robot_obs[:, :3], -POS_SCALE, POS_SCALE) / POS_SCALE
    d_orn = (actions[:, 3:6] - robot_obs[:, 3:6] + np.pi) % (2 * np.pi) - np.pi  # wrap to [-pi, pi)
    d_orn = np.clip(d_orn, -ORN_SCALE, ORN_SCALE) / ORN_SCALE
    return np.concatenate([d_pos, d_orn, actions[:, 6:7]], axis=1)  # (F, 7)


@dataclass
class PlaySegment:
    """A recorded segment with frame indices local to it (0 .. F-1).

    Attributes:
        frames: per-key (F, ...) arrays of the 6 core npz keys.
        windows: ``(start, end_inclusive, annotation, task)`` of the tasks the oracle confirmed.
        attempted: task names the expert ran, in order; ``completed`` the confirmed subset (in order).
    """

    frames: dict[str, np.ndarray]
    windows: list[tuple[int, int, str, str]] = field(default_factory=list)
    attempted: list[str] = field(default_factory=list)
    completed: list[str] = field(default_factory=list)

    @property
    def num_frames(self) -> int:
        """F."""
        return len(self.frames["robot_obs"])


class _Recorder:
    """Collects states t = 0 .. F (F + 1 states for F saved frames) and gripper commands."""

    def __init__(self, sim) -> None:
        self.sim = sim
        self.robot_obs: list[np.ndarray] = []
        self.scene_obs: list[np.ndarray] = []
        self.static: list[np.ndarray] = []
        self.gripper: list[np.ndarray] = []
        self.commands: list[float] = []
        self.observe()

    def observe(self) -> None:
        self.robot_obs.append(self.sim.robot_obs())
        self.scene_obs.append(self.sim.scene_obs())
        images = self.sim.render_cameras()
        self.static.append(images["static"])
        self.gripper.append(images["gripper"])

    def step(self, action: np.ndarray) -> None:
        self.sim.step(action)
        self.commands.append(-1.0 if action[6] <= 0 else 1.0)  # CALVIN rewrites gripper 0 to -1
        self.observe()

    @property
    def frame(self) -> int:
        """Index of the current (latest) state."""
        return len(self.robot_obs) - 1

    def arrays(self) -> dict[str, np.ndarray]:
        """The F = len(commands) saved frames; the final state only provides actions[F-1]."""
        num = len(self.commands)
        robot_obs = np.stack(self.robot_obs)  # (F+1, 15)
        actions = np.concatenate(
            [robot_obs[1 : num + 1, :6], np.array(self.commands)[:, None]], axis=1
        )  # (F, 7)
        return {
            "actions": actions,
            "rel_actions": relative_actions(actions, robot_obs[:num]),
            "robot_obs": robot_obs[:num],
            "scene_obs": np.stack(self.scene_obs[:num]),
            "rgb_static": np.stack(self.static[:num]),
            "rgb_gripper": np.stack(self.gripper[:num]),
        }


def draw_next_task(feasible: list[str], rng: np.random.Generator, weights: Mapping[str, float] | None) -> str:
    """One of the ``feasible`` tasks, with chances proportional to ``weights`` (missing tasks: 1).

    Why weights: drawn uniformly among the feasible tasks, the fixture tasks (feasible from almost any state)
    take most of a segment's later attempts, so most block tasks get a fraction of their demonstrations.
    None draws exactly as before (``rng.choice`` without probabilities), so default data does not change.
    """
    if weights is None:
        return str(rng.choice(feasible))
    chances = np.array([weights.get(task, 1.0) for task in feasible], dtype=np.float64)
    return str(rng.choice(feasible, p=chances / chances.sum()))


def record_segment(
    sim,
    num_tasks: int,
    rng: np.random.Generator,
    max_steps_per_task: int = 360,
    tasks: tuple[str, ...] = TASK_NAMES,
    first_task: str | None = None,
    windows_from_completion: bool = False,
    task_weights: Mapping[str, float] | None = None,
) -> PlaySegment:
    """Play ``num_tasks`` feasible tasks in a row from a random start state and record every frame.

    Args:
        sim: a fresh ``CalvinSimulation`` with cameras.
        num_tasks: task attempts in the segment (fewer when no task is feasible any more).
        rng: the segment's generator (start state, task choice, expert randomness, annotation choice).
        max_steps_per_task: expert step budget per task (CALVIN's rollout limit is 360).
        tasks: candidate task names.
        first_task: the segment's first task (its start state is drawn so that it is feasible); None: a
            random one of ``tasks``.
        windows_from_completion: start a window that follows a confirmed task at the frame where that task's
            oracle first fired (module docstring); False: where the expert starts the task.
        task_weights: relative chance of each task when the next one is drawn among the feasible ones
            (``draw_next_task``); None: uniform.
    """
    from lerobot_subgoalvla.envs.calvin.expert.scripted_expert import ScriptedExpert, is_feasible
    from lerobot_subgoalvla.envs.calvin.expert.start_states import sample_start_state
    from lerobot_subgoalvla.envs.calvin.oracle.tasks import TaskOracle

    oracle = TaskOracle()
    first_task = first_task or str(rng.choice(tasks))
    sample_start_state(first_task, sim, rng)
    recorder = _Recorder(sim)
    windows, attempted, completed = [], [], []
    task: str | None = first_task
    handover: int | None = None  # first frame at which the previous confirmed task's oracle held
    for _ in range(num_tasks):
        if task is None:
            logger.info("no feasible task left after %d tasks; ending the segment", len(attempted))
            break
        start_frame, start_info = recorder.frame, sim.get_info()
        fired: int | None = None
        expert = ScriptedExpert(sim, task, rng)
        while not expert.done and expert.steps < max_steps_per_task:
            action = expert.act()
            if expert.done:  # the script ended on this call: the action is a no-op hold, not recorded
                break
            recorder.step(action)
            # Checked only when asked for: the default data stays exactly what it was (and as fast).
            if (
                windows_from_completion
                and fired is None
                and oracle.is_completed(task, start_info, sim.get_info())
            ):
                fired = recorder.frame
        attempted.append(task)
        window_start = start_frame if handover is None else handover
        handover = None
        if recorder.frame > start_frame and oracle.is_completed(task, start_info, sim.get_info()):
            completed.append(task)
            annotation = str(rng.choice(TRAINING_ANNOTATIONS[task]))
            windows.append((window_start, recorder.frame, annotation, task))  # end may be the unsaved state
            if windows_from_completion:
                # A task confirmed only at the script's end (it fired on no step before) hands over there.
                handover = recorder.frame if fired is None else fired
        feasible = [name for name in tasks if is_feasible(name, sim)]
        if not feasible:  # e.g. a missed grasp left the gripper closed on nothing: open it and back off
            for _ in range(RECOVERY_STEPS):
                recorder.step(RECOVERY_ACTION)
            feasible = [name for name in tasks if is_feasible(name, sim)]
        task = draw_next_task(feasible, rng, task_weights) if feasible else None
    frames = recorder.arrays()
    last = len(recorder.commands) - 1
    windows = [(s, min(e, last), a, t) for s, e, a, t in windows if s <= last]  # clamp to saved frames
    return PlaySegment(frames, windows, attempted, completed)
