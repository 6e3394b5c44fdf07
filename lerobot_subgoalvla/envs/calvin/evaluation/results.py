"""Per-episode results of CALVIN's long-horizon evaluation: records, JSON lines, shards, lerobot-eval import.

One :class:`EpisodeResult` per evaluated chain (docs/calvin.md 4.3): how many of its five subtasks were
completed in a row before the first failure. Two sources produce them:

- the env, when given a ``results_path``, appends one JSON line per finished chain
  (:func:`append_episode_result`);
- lerobot-eval's ``eval_info.json``, where each chain is one ``task_id`` and
  ``per_task[*].metrics.sum_rewards`` holds the completed-subtask count (reward 1 per subtask), via
  :func:`episode_results_from_eval_info`.

Chains can be evaluated in shards (ranges of chain ids, on several processes or machines);
:func:`merge_results` joins the shards by ``chain_id`` and refuses duplicates, so no chain is counted twice.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lerobot_subgoalvla.calvin_vocab import check_task_name
from lerobot_subgoalvla.envs.calvin.protocol import CHAIN_LENGTH

logger = logging.getLogger(__name__)

#: Per-subtask outcomes (CALVIN's per-task counting, spec 4.4).
SUCCESS, FAILURE, NOT_ATTEMPTED = "success", "failure", "not_attempted"


@dataclass(frozen=True)
class EpisodeResult:
    """The outcome of one chain.

    Args:
        chain_id: index of the chain in the chain list (``generate_chains(num_chains)``).
        tasks: the chain's task names, in order.
        num_completed: subtasks completed in a row before the first failure (0..len(tasks)); CALVIN's
            "result".
        subtask_steps: env steps spent on each attempted subtask (the successful ones and the failed one), or
            None when unknown (results imported from ``eval_info.json``).
    """

    chain_id: int
    tasks: tuple[str, ...]
    num_completed: int
    subtask_steps: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        for task in self.tasks:
            check_task_name(task)
        if not 0 <= self.num_completed <= len(self.tasks):
            raise ValueError(
                f"chain {self.chain_id}: num_completed={self.num_completed} not in 0..{len(self.tasks)}"
            )
        attempted = min(self.num_completed + 1, len(self.tasks))
        if self.subtask_steps is not None and len(self.subtask_steps) != attempted:
            raise ValueError(
                f"chain {self.chain_id}: {len(self.subtask_steps)} subtask_steps for {attempted} attempted "
                "subtasks"
            )

    @property
    def outcomes(self) -> tuple[str, ...]:
        """Per subtask: success before the failure, the failed one, the rest not attempted (spec 4.4)."""
        failed = (FAILURE,) if self.num_completed < len(self.tasks) else ()
        rest = len(self.tasks) - self.num_completed - len(failed)
        return (SUCCESS,) * self.num_completed + failed + (NOT_ATTEMPTED,) * rest

    @property
    def steps(self) -> int | None:
        """Total env steps of the episode, when known."""
        return None if self.subtask_steps is None else sum(self.subtask_steps)

    def to_dict(self) -> dict[str, Any]:
        return {
            "chain_id": self.chain_id,
            "tasks": list(self.tasks),
            "num_completed": self.num_completed,
            "outcomes": list(self.outcomes),
            "steps": self.steps,
            "subtask_steps": None if self.subtask_steps is None else list(self.subtask_steps),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> EpisodeResult:
        steps = data.get("subtask_steps")
        result = cls(
            int(data["chain_id"]),
            tuple(data["tasks"]),
            int(data["num_completed"]),
            None if steps is None else tuple(int(s) for s in steps),
        )
        if "outcomes" in data and tuple(data["outcomes"]) != result.outcomes:
            raise ValueError(f"chain {result.chain_id}: outcomes {data['outcomes']} contradict num_completed")
        return result


#: lerobot-eval's task group of LH-MTLC chains (``CalvinEnvConfig.create_envs``; one task is "calvin_<task>").
CHAIN_TASK_GROUP = "calvin"


def append_episode_result(path: Path, result: EpisodeResult) -> None:
    """Append one JSON line (a single write, so concurrent appenders do not interleave lines)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as f:
        f.write(json.dumps(result.to_dict()) + "\n")


def read_episode_results(path: Path) -> list[EpisodeResult]:
    """All records of a JSON-lines results file, in file order."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"Results file {path} not found")
    text = path.read_text()
    lines = text.splitlines()
    results = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            results.append(EpisodeResult.from_dict(json.loads(line)))
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
            if number == len(lines) and not text.endswith("\n"):  # every record ends with a newline
                raise ValueError(
                    f"{path}:{number}: incomplete last line (its writer was stopped mid-line); rerun the "
                    "evaluation with --env.resume=true to redo that chain, or delete the line"
                ) from None
            raise ValueError(
                f"{path}:{number}: not an episode result ({err}); remove or fix that line"
            ) from None
    return results


def records_to_resume(path: Path) -> list[EpisodeResult]:
    """The finished records of a results file an evaluation continues (``--env.resume=true``).

    A last line without its newline is a record whose writer was stopped: it is cut off (a warning names it),
    so the resumed run redoes that chain and appends whole lines after whole lines. Any other bad line is
    an error, as in :func:`read_episode_results`.
    """
    path = Path(path)
    if not path.is_file():
        return []
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        keep = data.rfind(b"\n") + 1
        logger.warning(
            "%s: dropping an incomplete last line %r (its chain is evaluated again)", path, data[keep:]
        )
        with path.open("r+b") as f:
            f.truncate(keep)
    return read_episode_results(path)


def merge_results(shards: Mapping[str, Iterable[EpisodeResult]]) -> list[EpisodeResult]:
    """Join shards (name -> results) by chain id, sorted; a chain id seen twice is an error."""
    seen: dict[int, str] = {}
    merged: list[EpisodeResult] = []
    for source, results in shards.items():
        for result in results:
            if result.chain_id in seen:
                raise ValueError(
                    f"chain {result.chain_id} appears twice ({seen[result.chain_id]} and {source}); "
                    "each chain must be evaluated once - drop the overlapping shard"
                )
            seen[result.chain_id] = source
            merged.append(result)
    return sorted(merged, key=lambda r: r.chain_id)


def episode_results_from_eval_info(
    eval_info: Mapping[str, Any], chain_tasks: Mapping[int, Sequence[str]]
) -> list[EpisodeResult]:
    """Results from lerobot-eval's ``eval_info.json``: ``task_id`` = chain id, ``sum_rewards`` = completed
    count.

    Args:
        eval_info: the parsed ``eval_info.json`` (needs ``per_task[*].task_id`` and ``.metrics.sum_rewards``).
        chain_tasks: chain id -> its task names, from the chain list the evaluation used.

    Raises:
        ValueError: missing fields, a chain id outside ``chain_tasks``, not exactly one episode per chain, a
            non-integer reward sum, or a success that is not 5 of 5 (a single-task evaluation, whose task_id
            is the task's CALVIN id, would otherwise pass for a chain).
    """
    if not isinstance(eval_info, Mapping) or not isinstance(eval_info.get("per_task"), list):
        raise ValueError("eval_info has no 'per_task' list; pass the eval_info.json that lerobot-eval wrote")
    results = []
    for entry in eval_info["per_task"]:
        group = entry.get("task_group", CHAIN_TASK_GROUP) if isinstance(entry, Mapping) else CHAIN_TASK_GROUP
        if group != CHAIN_TASK_GROUP:
            raise ValueError(
                f"eval_info task group {group!r} is a single-task evaluation, not LH-MTLC chains; the report "
                "needs lerobot-eval --env.task=lh_mtlc (or its --env.results_path JSON lines)"
            )
        try:
            chain_id, sums = int(entry["task_id"]), entry["metrics"]["sum_rewards"]
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"eval_info per_task entry lacks task_id/metrics.sum_rewards ({err})") from None
        if chain_id not in chain_tasks:
            raise ValueError(
                f"eval_info task_id {chain_id} is not in the chain list; pass the chains file used"
            )
        if len(sums) != 1:
            raise ValueError(
                f"chain {chain_id} has {len(sums)} episodes; CALVIN runs each chain once "
                "(lerobot-eval --eval.n_episodes=1)"
            )
        completed = round(float(sums[0]))
        if abs(float(sums[0]) - completed) > 1e-6:
            raise ValueError(f"chain {chain_id}: sum_rewards {sums[0]} is not a whole number of subtasks")
        successes = entry["metrics"].get("successes")
        if successes is not None and bool(successes[0]) != (completed == CHAIN_LENGTH):
            raise ValueError(
                f"task_id {chain_id}: success={bool(successes[0])} after {completed} subtask(s) is not a "
                "chain result (a chain succeeds at 5/5): this eval_info.json is from a single-task "
                "evaluation; the LH-MTLC report needs lerobot-eval --env.task=lh_mtlc"
            )
        results.append(EpisodeResult(chain_id, tuple(chain_tasks[chain_id]), completed))
    return results
