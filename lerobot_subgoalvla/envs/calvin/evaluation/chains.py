"""CALVIN's long-horizon evaluation (LH-MTLC): the five-task chains and their per-episode results.

Clean-room re-implementation of calvin_agent ``evaluation/multistep_sequences.py`` (``get_sequences``) and
``evaluation/utils.py`` (``get_env_state_for_initial_condition``), docs/calvin.md sections 4.1-4.2. The output
is identical, chain by chain, to CALVIN's official 1000 chains (spec 4.1 check values are the tests):

1. 192 symbolic initial states: the product of :data:`SYMBOLIC_VALUES` in key order, kept iff one or two
   blocks are on the table and each slider slot holds at most one block.
2. Quotas: ``np.array_split(range(num_chains), 192)``; state ``i`` draws with ``RandomState(i)``:
   ``choice(34, 5, replace=False)`` over the task list until it has its quota of valid sequences (each task
   has exactly one applicable alternative in turn, five distinct categories).
3. The ``(state, sequence)`` list, in state order, is shuffled with ``RandomState(0).shuffle``.
4. Simulator state (spec 4.2): fixed :data:`EVAL_ROBOT_OBS`; ``scene_obs`` from the symbolic state, the two
   table slots shuffled and three block yaws drawn from ``RandomState(h)``, ``h`` = FNV-1 32-bit (initial
   value 0) over the UTF-16-LE bytes of ``str(state.values())`` as CPython prints it.

Per-episode results (:class:`EpisodeResult`) are JSON lines written by the env (``results_path``) or derived
from lerobot-eval's ``eval_info.json`` (one ``task_id`` per chain, ``sum_rewards`` = completed subtasks);
shards evaluated on different machines (``--start/--stop``) are merged by ``chain_id``.

Usage::

    subgoalvla-calvin-chains --output chains.json                       # the official 1000 chains
    subgoalvla-calvin-chains --output shard1.json --start 500 --stop 1000   # chain ids 500..999
"""

from __future__ import annotations

import argparse
import functools
import itertools
import json
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from lerobot_subgoalvla.atomic_files import atomic_write
from lerobot_subgoalvla.calvin_vocab import BLOCK_COLORS, TASK_NAMES, check_task_name
from lerobot_subgoalvla.cli_errors import OneLineArgumentParser, user_errors

# The symbolic -> simulator mapping lives in chain_scene.py and per-episode results in results.py; both are
# re-exported here because chains.py is the env's seam (docs/architecture.md).
from lerobot_subgoalvla.envs.calvin.evaluation.chain_scene import (
    EVAL_ROBOT_OBS,
    SYMBOLIC_VALUES,
    fnv1_32,
    scene_obs_for_state,
    state_seed,
)

# Per-episode results live in results.py; re-exported here because chains.py is the env's seam
# (docs/architecture.md).
from lerobot_subgoalvla.envs.calvin.evaluation.results import (
    EpisodeResult,
    append_episode_result,
    episode_results_from_eval_info,
    merge_results,
    read_episode_results,
)
from lerobot_subgoalvla.envs.calvin.protocol import CHAIN_LENGTH

__all__ = [
    "EVAL_ROBOT_OBS", "SYMBOLIC_TASKS", "SYMBOLIC_VALUES", "TASK_CATEGORIES", "Chain", "EpisodeResult",
    "append_episode_result", "apply_task", "episode_results_from_eval_info", "fnv1_32", "generate_chains",
    "initial_states", "is_valid_sequence", "load_chains", "main", "merge_results", "read_episode_results",
    "save_chains", "scene_obs_for_state", "state_seed",
]  # fmt: skip

logger = logging.getLogger(__name__)

SymbolicState = dict[str, Any]

_SLIDER_SLOTS = ("slider_right", "slider_left")


# ------------------------------------------------------------------------------------ symbolic task model
@dataclass(frozen=True)
class Alternative:
    """One way a task applies: every ``condition`` key matches (a tuple value = "one of") -> ``effect``."""

    condition: Mapping[str, Any]
    effect: Mapping[str, Any]

    def holds(self, state: Mapping[str, Any]) -> bool:
        return all(
            state[k] in v if isinstance(v, tuple) else state[k] == v for k, v in self.condition.items()
        )


def _alt(condition: dict[str, Any], effect: dict[str, Any]) -> Alternative:
    return Alternative(MappingProxyType(condition), MappingProxyType(effect))


def _symbolic_tasks() -> dict[str, tuple[tuple[Alternative, ...], int]]:
    """Task -> (alternatives, category), spec 4.1's table; built in TASK_NAMES order (CALVIN's list order)."""
    table: dict[str, tuple[tuple[Alternative, ...], int]] = {}
    for c in BLOCK_COLORS:
        on_table = _alt({f"{c}_block": "table", "grasped": 0}, {f"{c}_block": "table"})
        for verb, side in itertools.product(("rotate", "push"), ("right", "left")):
            table[f"{verb}_{c}_block_{side}"] = ((on_table,), 1)
        grab = {f"{c}_block": "grasped", "grasped": 1}
        table[f"lift_{c}_block_table"] = ((_alt({f"{c}_block": "table", "grasped": 0}, grab),), 4)
        table[f"lift_{c}_block_slider"] = (
            (_alt({f"{c}_block": "slider_left", "slider": "right", "grasped": 0}, grab),
             _alt({f"{c}_block": "slider_right", "slider": "left", "grasped": 0}, grab)), 5)  # fmt: skip
        table[f"lift_{c}_block_drawer"] = (
            (_alt({f"{c}_block": "drawer", "drawer": "open", "grasped": 0}, grab),),
            6,
        )
    for task, key, before, after, category in (
        ("move_slider_left", "slider", "right", "left", 2),
        ("move_slider_right", "slider", "left", "right", 2),
        ("open_drawer", "drawer", "closed", "open", 3), ("close_drawer", "drawer", "open", "closed", 3),
        ("turn_on_lightbulb", "lightbulb", 0, 1, 8), ("turn_off_lightbulb", "lightbulb", 1, 0, 8),
        ("turn_on_led", "led", 0, 1, 8), ("turn_off_led", "led", 1, 0, 8),
    ):  # fmt: skip
        table[task] = ((_alt({key: before, "grasped": 0}, {key: after}),), category)
    blocks = [f"{c}_block" for c in BLOCK_COLORS]
    table["place_in_slider"] = (tuple(
        _alt({b: "grasped", "slider": side, "grasped": 1}, {b: f"slider_{side}", "grasped": 0})
        for b in blocks for side in ("right", "left")), 7)  # fmt: skip
    table["place_in_drawer"] = (tuple(
        _alt({b: "grasped", "drawer": "open", "grasped": 1}, {b: "drawer", "grasped": 0})
        for b in blocks), 7)  # fmt: skip
    pairs = list(itertools.permutations(blocks, 2))
    table["stack_block"] = (tuple(
        _alt({top: "grasped", bottom: "table", "grasped": 1},
             {top: "stacked_top", bottom: "stacked_bottom", "grasped": 0})
        for top, bottom in pairs), 10)  # fmt: skip
    table["unstack_block"] = (tuple(
        _alt({top: "stacked_top", bottom: "stacked_bottom", "grasped": 0}, {top: "table", bottom: "table"})
        for top, bottom in pairs), 11)  # fmt: skip
    table["push_into_drawer"] = (tuple(
        _alt({b: "table", **{o: _SLIDER_SLOTS for o in blocks if o != b}, "drawer": "open", "grasped": 0},
             {b: "drawer", "grasped": 0}) for b in blocks), 9)  # fmt: skip
    return {task: table[task] for task in TASK_NAMES}


_TASK_TABLE = _symbolic_tasks()
#: Task -> its alternatives (condition -> effect), spec 4.1.
SYMBOLIC_TASKS: Mapping[str, tuple[Alternative, ...]] = MappingProxyType(
    {t: a for t, (a, _) in _TASK_TABLE.items()}
)
#: Task -> category (1-11); a chain never repeats a category.
TASK_CATEGORIES: Mapping[str, int] = MappingProxyType({t: c for t, (_, c) in _TASK_TABLE.items()})


def initial_states() -> list[SymbolicState]:
    """The 192 symbolic initial states in CALVIN's order (spec 4.1)."""
    states = []
    for values in itertools.product(*SYMBOLIC_VALUES.values()):
        blocks = values[4:7]
        if blocks.count("table") in (1, 2) and all(blocks.count(slot) < 2 for slot in _SLIDER_SLOTS):
            states.append(dict(zip(SYMBOLIC_VALUES, values, strict=True)))
    return states


def apply_task(state: Mapping[str, Any], task: str) -> SymbolicState | None:
    """The symbolic state after ``task``, or None unless exactly one alternative applies (CALVIN's rule)."""
    applicable = [alt for alt in SYMBOLIC_TASKS[task] if alt.holds(state)]
    return {**state, **applicable[0].effect} if len(applicable) == 1 else None


def is_valid_sequence(state: Mapping[str, Any], tasks: Sequence[str]) -> bool:
    """Each task applies in turn and no category repeats (CALVIN's ``check_sequence``)."""
    current: Mapping[str, Any] | None = state
    for task in tasks:
        current = apply_task(current, task)
        if current is None:
            return False
    return len({TASK_CATEGORIES[t] for t in tasks}) == len(tasks)


class _TransitionTable:
    """Every symbolic state reachable from the initial states, as ids, with ``next[state, task]`` (sink if the
    task does not apply with exactly one alternative): vectorised :func:`is_valid_sequence` for many draws."""

    def __init__(self) -> None:
        self.ids: dict[tuple[Any, ...], int] = {}
        frontier = [tuple(s.values()) for s in initial_states()]
        rows: list[list[tuple[Any, ...] | None]] = []
        while frontier:
            key = frontier.pop()
            if key in self.ids:
                continue
            self.ids[key] = len(rows)
            after = [apply_task(dict(zip(SYMBOLIC_VALUES, key, strict=True)), t) for t in SYMBOLIC_TASKS]
            rows.append([None if a is None else tuple(a.values()) for a in after])
            frontier += [a for a in rows[-1] if a is not None and a not in self.ids]
        self.sink = len(rows)
        self.next = np.full((self.sink + 1, len(SYMBOLIC_TASKS)), self.sink, dtype=np.int64)
        for sid, row in enumerate(rows):
            self.next[sid] = [self.sink if a is None else self.ids[a] for a in row]
        self.categories = np.array(list(TASK_CATEGORIES.values()))

    def valid(self, state: Mapping[str, Any], seqs: np.ndarray) -> np.ndarray:
        """(N,) bool: which rows of ``seqs`` (N, 5) task indices are valid chains from ``state``."""
        current = np.full(len(seqs), self.ids[tuple(state.values())])
        for column in seqs.T:
            current = self.next[current, column]
        categories = np.sort(self.categories[seqs], axis=1)
        return (current != self.sink) & np.all(np.diff(categories, axis=1) != 0, axis=1)


#: ``random_interval(i)`` bounds of a Fisher-Yates shuffle of 34 items, i =
#: 33..1, as ``randint`` highs (i + 1).
_SHUFFLE_HIGHS = np.arange(len(TASK_NAMES), 1, -1, dtype=np.int32)


def _draw_choices(rs: np.random.RandomState, count: int) -> np.ndarray:
    """``count`` successive ``rs.choice(34, 5, replace=False)`` draws, (count, 5), vectorised.

    Legacy ``choice`` without replacement is ``permutation(34)[:5]``: a Fisher-Yates shuffle swapping item
    ``i`` with ``j = random_interval(i)`` for i = 33..1 (masked rejection sampling on 32-bit draws). Legacy
    ``randint`` with an array of highs draws each ``j`` with exactly that rejection rule, in order, so the
    random stream and the result are identical to calling ``choice`` ``count`` times (tested), about 10x
    faster (``benchmarks/calvin_chains.py``).
    """
    n = len(_SHUFFLE_HIGHS) + 1
    # int32: 32-bit masked rejection, same stream as random_interval (8/16-bit dtypes would buffer: different)
    highs = np.tile(_SHUFFLE_HIGHS, count)
    swaps = rs.randint(0, highs, dtype=np.int32).reshape(count, n - 1).T  # (33, count)
    items = np.repeat(np.arange(n, dtype=np.int8)[:, None], count, axis=1)  # (34, count)
    flat, columns = items.reshape(-1), np.arange(count)
    for step, i in enumerate(_SHUFFLE_HIGHS - 1):
        target = swaps[step] * count + columns  # flat index of items[j, column]
        held = items[i].copy()
        items[i] = flat[target]
        flat[target] = held
    return items[:CHAIN_LENGTH].T.astype(np.int64)  # (count, 5)


def _sample_sequences(
    state: SymbolicState, count: int, seed: int, table: _TransitionTable
) -> list[tuple[str, ...]]:
    """CALVIN's ``get_sequences_for_state2``: the first ``count`` valid draws of ``RandomState(seed)``.

    Draws are made in batches; draws past the last accepted one are discarded, which is harmless because the
    generator belongs to this state alone.
    """
    rs, names = np.random.RandomState(seed), list(SYMBOLIC_TASKS)
    found: list[tuple[str, ...]] = []
    drawn, batch = 0, 4096
    while len(found) < count:
        draws = _draw_choices(rs, batch)
        for row in draws[table.valid(state, draws)][: count - len(found)]:
            found.append(tuple(names[k] for k in row))
        drawn += batch
        # next batch: the expected number of draws still needed (+25 %), from the acceptance rate so far
        rate = max(len(found), 1) / drawn
        batch = int(np.clip(1.25 * (count - len(found)) / rate, 1024, 1 << 16))
    return found


# ------------------------------------------------------------------------------------------------ chains
@dataclass(frozen=True, eq=False)
class Chain:
    """One evaluation chain: symbolic initial state (CALVIN's keys), five task names, its (24,) scene_obs."""

    initial_state: Mapping[str, Any]
    tasks: tuple[str, ...]
    scene_obs: np.ndarray

    def to_dict(self, chain_id: int) -> dict[str, Any]:
        return {"chain_id": chain_id, "initial_state": dict(self.initial_state), "tasks": list(self.tasks),
                "scene_obs": [float(x) for x in self.scene_obs]}  # fmt: skip

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Chain:
        scene_obs = np.asarray(data["scene_obs"], dtype=np.float64)
        if scene_obs.shape != (24,) or len(data["tasks"]) != CHAIN_LENGTH:
            raise ValueError(f"chain {data.get('chain_id')}: expected 5 tasks and a (24,) scene_obs")
        if set(data["initial_state"]) != set(SYMBOLIC_VALUES):
            raise ValueError(
                f"chain {data.get('chain_id')}: initial_state keys must be {list(SYMBOLIC_VALUES)}"
            )
        tasks = tuple(check_task_name(task) for task in data["tasks"])
        return cls({k: data["initial_state"][k] for k in SYMBOLIC_VALUES}, tasks, scene_obs)


@functools.lru_cache(maxsize=4)
def _chain_plan(num_chains: int) -> tuple[tuple[int, tuple[str, ...]], ...]:
    """(initial-state index, task names) per chain, in CALVIN's final (shuffled) order. Cached: ~10 s of
    CPU."""
    states = initial_states()
    quotas = [len(part) for part in np.array_split(np.arange(num_chains), len(states))]
    table = _TransitionTable()
    pairs = [(i, seq) for i, (state, quota) in enumerate(zip(states, quotas, strict=True))
             for seq in _sample_sequences(state, quota, seed=i, table=table)]  # fmt: skip
    np.random.RandomState(0).shuffle(pairs)
    return tuple(pairs)


def generate_chains(num_chains: int = 1000) -> list[Chain]:
    """CALVIN's evaluation chains for ``num_chains`` (1000 = the official benchmark list), spec 4.1-4.2.

    The first call for a given ``num_chains`` samples about 8 million candidate sequences (roughly 10 s of CPU
    for 1000 chains); later calls in the same process reuse the result.
    """
    if num_chains < 1:
        raise ValueError(f"num_chains must be >= 1, got {num_chains}")
    states = initial_states()
    scene = [scene_obs_for_state(state) for state in states]
    return [Chain(dict(states[i]), seq, scene[i].copy()) for i, seq in _chain_plan(num_chains)]


def save_chains(path: Path, chains: Sequence[Chain], start: int = 0) -> None:
    """Write chains (ids ``start``...) as a JSON list, atomically."""
    atomic_write(path, json.dumps([c.to_dict(start + k) for k, c in enumerate(chains)], indent=1))


def load_chains(path: Path) -> dict[int, Chain]:
    """Chain id -> chain from a file written by :func:`save_chains` / ``subgoalvla-calvin-chains``."""
    try:
        entries = json.loads(Path(path).read_text())
        chains = {int(e["chain_id"]): Chain.from_dict(e) for e in entries}
        if len(chains) != len(entries):
            raise ValueError("a chain id appears twice")
        return chains
    except FileNotFoundError:
        raise FileNotFoundError(
            f"Chains file {path} not found; create it with subgoalvla-calvin-chains"
        ) from None
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        raise ValueError(
            f"Chains file {path} is malformed ({err}); regenerate it with subgoalvla-calvin-chains"
        ) from None


# ------------------------------------------------------------------------------------------------------ CLI
def configure_cli_logging() -> None:
    """INFO-level logging for the CLIs; importing LeRobot may already have set up a WARNING-level root
    logger."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger().setLevel(logging.INFO)


def _parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = OneLineArgumentParser(prog="subgoalvla-calvin-chains", description=__doc__.split("\n")[0])
    parser.add_argument("--num-chains", type=int, default=1000, help="chains in the list (CALVIN: 1000)")
    parser.add_argument("--output", type=Path, required=True, help="JSON file to write")
    parser.add_argument("--start", type=int, default=0, help="first chain id to write (for shards)")
    parser.add_argument("--stop", type=int, default=None, help="one past the last chain id (default: all)")
    args = parser.parse_args(argv)
    args.stop = args.num_chains if args.stop is None else args.stop
    if args.num_chains < 1 or not 0 <= args.start < args.stop <= args.num_chains:
        parser.error(
            "need 0 <= --start < --stop <= --num-chains >= 1, "
            f"got {args.start}, {args.stop}, {args.num_chains}"
        )
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """``subgoalvla-calvin-chains``: write chains ``[start, stop)`` of CALVIN's list as JSON."""
    configure_cli_logging()
    with user_errors(logger):
        args = _parse_args(argv)
        chains = generate_chains(args.num_chains)[args.start : args.stop]
        save_chains(args.output, chains, start=args.start)
    logger.info("Wrote chains %d..%d of %d to %s", args.start, args.stop - 1, args.num_chains, args.output)
    return 0
