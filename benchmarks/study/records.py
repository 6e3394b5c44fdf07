"""The study's results file, ``benchmarks/study/results.json``: a list of records, one per (method, setting,
task, seed, training samples, training frames), rewritten atomically under a file lock.

Every record says where it came from: ``commit`` (the code's git commit, ``+dirty`` when the tree differed;
None where it was not recorded), ``recorded_in`` (the commit that added a record made before records named
their commit), ``code_era`` (which training code it ran: :data:`ERA_COMMITS`; None where the history does not
establish it), ``data_command``, ``train_command`` and ``eval_command`` (None where not recorded), and a
``provenance`` note wherever one of those is missing.
"""

from __future__ import annotations

import fcntl
import json
import subprocess
from pathlib import Path

RESULTS_PATH = Path(__file__).resolve().parent / "results.json"
REPO_ROOT = Path(__file__).resolve().parents[2]

#: Commits after which the same training command and seed train another model. A record's ``code_era`` is the
#: last of them its code contains (``pre-`` the first where it contains none); the tables never pool runs of
#: two eras. A commit that changes what a seed trains is added here.
ERA_COMMITS = (
    ("b6dfa55", "the policy's training draws come from an RNG keyed by (seed, step, rank)"),
    ("06900d6", "the policy's vocabulary, cameras and angles come from the dataset's contract"),
)
FIRST_ERA = f"pre-{ERA_COMMITS[0][0]}"
#: The keys every record carries (values may be None where a ``provenance`` note says why).
PROVENANCE_KEYS = ("commit", "code_era", "data_command", "train_command", "eval_command")


def code_era(commit: str, root: Path = REPO_ROOT) -> str:
    """The era (:data:`ERA_COMMITS`) of the code at ``commit`` (``+dirty`` ignored), from the git history."""
    era = FIRST_ERA
    for boundary, _ in ERA_COMMITS:
        command = ["git", "merge-base", "--is-ancestor", boundary, commit.removesuffix("+dirty")]
        code = subprocess.run(command, cwd=root, capture_output=True).returncode
        if code not in (0, 1):
            raise ValueError(f"git cannot order {commit} against {boundary} in {root} (a shallow clone?)")
        era = boundary if code == 0 else era
    return era


def missing_provenance(record: dict) -> list[str]:
    """What a record lacks to say where it came from: a provenance key, a commit or the commit that recorded
    it, or the ``provenance`` note that explains a None."""
    missing = [key for key in PROVENANCE_KEYS if key not in record]
    if not (record.get("commit") or record.get("recorded_in")):
        missing.append("commit or recorded_in")
    unknown = [key for key in PROVENANCE_KEYS if key in record and record[key] is None]
    if unknown and not record.get("provenance"):
        missing.append(f"provenance (a note on the missing {', '.join(unknown)})")
    return missing


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


def eval_time_fields(seconds: float | None, episodes: int) -> dict:
    """``eval_seconds`` and ``eval_seconds_per_episode`` (the tables' eval s/ep column) of an evaluation that
    took ``seconds`` of wall time for ``episodes`` episodes; both None where the time was not written."""
    if seconds is None:
        return {"eval_seconds": None, "eval_seconds_per_episode": None}
    return {"eval_seconds": round(seconds, 1), "eval_seconds_per_episode": round(seconds / episodes, 2)}


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
