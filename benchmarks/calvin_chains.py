"""Speed of CALVIN's chain generator and of the task oracle (docs/calvin_evaluation.md).

Side by side in one run, CPU time (``time.process_time``), medians over ``--repeats``:

* ``reference``: CALVIN's sampler - one ``RandomState.choice(34, 5, replace=False)`` call and one symbolic
  check per candidate sequence - over the first ``--states`` initial states with the official quota;
* ``vectorised``: ``chains._sample_sequences`` (batched masked-rejection draws + transition table) on the same
  states; the sequences must be identical;
* ``generate_chains(1000)``: the full official list, uncached, once;
* ``oracle``: ``TaskOracle.completed_tasks`` over all 34 tasks for one (start, end) pair of info dicts.

Usage:
    python benchmarks/calvin_chains.py --states 8 --repeats 3
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from lerobot_subgoalvla.envs.calvin.evaluation import chains
from lerobot_subgoalvla.envs.calvin.oracle.tasks import TaskOracle


def _reference(state: dict, count: int, seed: int) -> list[tuple[str, ...]]:
    rs, names, found = np.random.RandomState(seed), list(chains.SYMBOLIC_TASKS), []
    while len(found) < count:
        seq = tuple(names[i] for i in rs.choice(len(names), size=5, replace=False))
        if chains.is_valid_sequence(state, seq):
            found.append(seq)
    return found


def _cpu(fn) -> tuple[float, object]:
    start = time.process_time()
    out = fn()
    return time.process_time() - start, out


def _info(uid_offset: float) -> dict:
    contact = (0, 0, 2, -1, -1, (0, 0, 0), (0, 0, 0), (0, 0, 1), 0.0, 1.0, 0.0, (1, 0, 0), 0.0, (0, 1, 0))
    block = {
        "current_pos": np.array([uid_offset, 0.0, 0.46]),
        "current_orn": np.array([0.0, 0.0, 0.0, 1.0]),
        "current_lin_vel": np.zeros(3),
        "current_ang_vel": np.zeros(3),
        "contacts": [contact],
    }
    return {
        "robot_info": {"uid": 1, "contacts": []},
        "scene_info": {
            "fixed_objects": {
                "table": {"uid": 2, "links": {"base_link": -1, "drawer_link": 3, "plank_link": 6}}
            },
            "movable_objects": {
                n: {**block, "uid": u} for n, u in (("block_red", 3), ("block_blue", 4), ("block_pink", 5))
            },
            "doors": {"base__slide": {"current_state": 0.0}, "base__drawer": {"current_state": 0.0}},
            "lights": {"lightbulb": {"logical_state": 0}, "led": {"logical_state": 0}},
        },
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--states", type=int, default=8, help="initial states for the sampler comparison")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    states = chains.initial_states()[: args.states]
    table = chains._TransitionTable()
    ref_t, vec_t = [], []
    for _ in range(args.repeats):
        t, ref = _cpu(lambda: [_reference(s, 6, i) for i, s in enumerate(states)])
        ref_t.append(t)
        t, vec = _cpu(lambda: [chains._sample_sequences(s, 6, i, table) for i, s in enumerate(states)])
        vec_t.append(t)
        assert ref == vec, "vectorised sampler diverged from CALVIN's per-draw sampler"
    chains._chain_plan.cache_clear()
    full_t, _ = _cpu(lambda: chains.generate_chains(1000))
    oracle, start, end = TaskOracle(), _info(0.0), _info(0.05)
    oracle_t = statistics.median(
        _cpu(lambda: [oracle.completed_tasks(start, end) for _ in range(100)])[0] / 100
        for _ in range(args.repeats)
    )
    ref_m, vec_m = statistics.median(ref_t), statistics.median(vec_t)
    print(f"{'measurement':<44} {'CPU s (median)':>15} {'ratio':>8}")
    print(f"{f'reference sampler, {args.states} states x 6 chains':<44} {ref_m:>15.3f} {1.0:>8.1f}")
    print(f"{'vectorised sampler, same draws':<44} {vec_m:>15.3f} {ref_m / vec_m:>8.1f}")
    print(f"{'generate_chains(1000), uncached':<44} {full_t:>15.3f} {'':>8}")
    print(f"{'oracle.completed_tasks, 34 tasks (ms)':<44} {oracle_t * 1e3:>15.3f} {'':>8}")


if __name__ == "__main__":
    main()
