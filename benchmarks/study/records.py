"""The study's results file, ``benchmarks/study/results.json``: a list of records, one per (method, setting,
task, seed, training samples, training frames), rewritten atomically under a file lock."""

from __future__ import annotations

import fcntl
import json
from pathlib import Path

RESULTS_PATH = Path(__file__).resolve().parent / "results.json"


def load_records(path: Path = RESULTS_PATH) -> list[dict]:
    return json.loads(path.read_text()) if path.is_file() else []


def record_key(record: dict) -> tuple:
    """What identifies a record: (method, setting, task, seed, training samples, training frames). The frames
    tell two generations of a dataset apart (the same command on another pybullet build or expert version
    makes other episodes); None where a record does not name them."""
    fields = ("method", "setting", "task", "seed", "train_samples")
    return (*(record[name] for name in fields), record.get("train_frames"))


def store_records(records: list[dict], path: Path = RESULTS_PATH) -> None:
    """Add ``records`` to the results file, replacing those with the same :func:`record_key` (an evaluation
    continued to more episodes); written to a temporary file, then renamed."""
    replaced = {record_key(r) for r in records}
    # Two study commands may store at once: the lock keeps one from dropping the other's records.
    with path.with_suffix(".lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        merged = [r for r in load_records(path) if record_key(r) not in replaced] + records
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(merged, indent=1) + "\n")
        tmp.replace(path)


def chain_record_fields(results: Path) -> dict:
    """A chain results file (``--env.results_path``) as record fields: ``episodes`` (chains), ``successes``
    (chains with all five subtasks done), ``avg_len`` and ``chain_sr`` (LH-1..5)."""
    from lerobot_subgoalvla.envs.calvin.evaluation.report import summarize
    from lerobot_subgoalvla.envs.calvin.evaluation.results import read_episode_results

    report = summarize(read_episode_results(results))
    return {
        "episodes": report.num_chains,
        "successes": round(report.chain_sr[5] * report.num_chains),
        "avg_len": round(report.avg_seq_len, 3),
        "chain_sr": {str(k): round(v, 4) for k, v in report.chain_sr.items()},
    }
