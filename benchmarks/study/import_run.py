"""Record a finished end-to-end run (``scripts/demo.sh`` or ``scripts/metaworld.sh``) in the study's results
file, with the commit and the exact commands that made it, so the study does not train such a run twice.

A run folder holds ``train.log``, ``train/checkpoints/last/pretrained_model/train_config.json`` (steps, batch
size and seed are read from it; a run kept in ``benchmarks/study/runs/`` has it in ``pretrained_model/``) and
``eval/<task>/eval_info.json`` (plus ``eval/lh_mtlc/results.jsonl`` for CALVIN's chains). One record per
evaluated task. An evaluation on other seeds (``scripts/metaworld.sh``'s ``eval_seed<N>/``) is recorded with
``--eval-dir`` in its own setting (``metaworld_mt10_heldout``: seeds chosen after every recipe choice), so
records of two seed ranges are never pooled or overwritten. The data's size comes from the dataset
(``--dataset``) or, where it is no longer on this machine, from the records of a run on the same data
(``--dataset-of METHOD``). A policy trained further in new runs (``lerobot-train --policy.path``) is recorded
from its last run's folder with ``--earlier-run`` for each run before: samples and training time are the sum.

Usage::

    python benchmarks/study/import_run.py outputs/mt10/subgoalvla --dataset outputs/mt10/dataset \\
        --method subgoalvla --setting metaworld_mt10 --scene metaworld --commit "$(git rev-parse HEAD)" \\
        --data-command "..." --train-command "..." --eval-command "..."
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path

from common import LH_MTLC, dataset_size, machine
from records import chain_record_fields, code_era, eval_time_fields, load_records, store_records

SETTINGS = ("multi_task", "metaworld_mt10", "metaworld_mt10_heldout")
#: A setting whose runs are those of another one, evaluated again: its data sizes are that setting's.
TRAINED_FOR = {"metaworld_mt10_heldout": "metaworld_mt10"}


def _eval_seconds(eval_dir: Path, task: str) -> float | None:
    """Wall seconds of ``lerobot-eval`` for ``task`` (its ``overall.eval_s``), None where not written."""
    overall = json.loads((eval_dir / task / "eval_info.json").read_text()).get("overall", {})
    seconds = overall.get("eval_s")
    return None if seconds is None else float(seconds)


#: Where a run folder keeps its train_config.json: scripts/*.sh's layout, a kept run's, then the folder itself
#: (an earlier run of a policy trained over several lerobot-train runs keeps only its config and log).
CHECKPOINT_FOLDERS = (
    Path("train") / "checkpoints" / "last" / "pretrained_model",
    Path("pretrained_model"),
    Path("."),
)


def _train_config(run_dir: Path) -> dict:
    for folder in CHECKPOINT_FOLDERS:
        path = run_dir / folder / "train_config.json"
        if path.is_file():
            return json.loads(path.read_text())
    raise SystemExit(
        f"{run_dir / CHECKPOINT_FOLDERS[0] / 'train_config.json'} is missing; pass the folder of a run "
        "scripts/*.sh trained or one kept in benchmarks/study/runs/"
    )


def dataset_size_of(method: str, setting: str, stored: list[dict]) -> dict[str, int]:
    """``train_episodes`` and ``train_frames`` of the ``stored`` records of ``method`` in ``setting`` (or in
    the setting it evaluates the runs of again: :data:`TRAINED_FOR`)."""
    settings = {setting, TRAINED_FOR.get(setting, setting)}
    sizes = {
        (r["train_episodes"], r["train_frames"])
        for r in stored
        if r["method"] == method and r["setting"] in settings and "train_frames" in r
    }
    if len(sizes) != 1:
        found = "none" if not sizes else f"{len(sizes)} different sizes"
        raise SystemExit(
            f"--dataset-of {method}: {found} among its {setting} records; pass --dataset instead"
        )
    episodes, frames = sizes.pop()
    return {"train_episodes": episodes, "train_frames": frames}


def _training(run_dir: Path) -> tuple[dict, list[dict], int, float | None]:
    """(train_config, the log's step lines, samples seen, wall seconds) of the lerobot-train run in
    ``run_dir``."""
    from lerobot_subgoalvla.demo_report import parse_train_log, train_wall_seconds

    log = parse_train_log(run_dir / "train.log")
    if not log:
        raise SystemExit(f"{run_dir / 'train.log'} has no lerobot-train step lines; is the run trained?")
    config = _train_config(run_dir)
    return config, log, config["steps"] * config["batch_size"], train_wall_seconds(run_dir / "train.log")


def records_from_run(
    run_dir: Path,
    data_size: dict[str, int],
    provenance: dict,
    eval_dir: Path | None = None,
    earlier_runs: Sequence[Path] = (),
) -> list[dict]:
    """One record per task evaluated in ``eval_dir`` (default ``run_dir/eval``; and one for its chains), each
    carrying ``provenance`` (method, setting, scene, commit and the commands) and ``data_size``
    (``dataset_size``'s fields). A policy trained over several lerobot-train runs (``--policy.path`` of the
    one before) names the ``earlier_runs``: their samples and wall seconds are added to ``run_dir``'s."""
    from lerobot_subgoalvla.demo_report import read_task_results

    config, log, samples, seconds = _training(run_dir)
    for earlier in earlier_runs:
        _, _, earlier_samples, earlier_seconds = _training(earlier)
        samples += earlier_samples
        seconds = None if seconds is None or earlier_seconds is None else seconds + earlier_seconds
    training = {
        **provenance,
        "seed": config["seed"],
        "train_samples": samples,
        **data_size,
        "train_seconds": None if seconds is None else round(seconds, 1),
        "samples_per_s": log[-1].get("smp/s"),
        "machine": machine(),
        # The study continues the evaluation of a recorded run from here (common.execute).
        "source": str(run_dir),
    }
    eval_dir = run_dir / "eval" if eval_dir is None else eval_dir
    records = [
        {
            **training,
            "task": task,
            "episodes": result["episodes"],
            "successes": result["successes"],
            **eval_time_fields(_eval_seconds(eval_dir, task), result["episodes"]),
        }
        for task, result in read_task_results(eval_dir).items()
    ]
    chains = eval_dir / LH_MTLC / "results.jsonl"
    if chains.is_file():
        records.append({**training, "setting": LH_MTLC, "task": LH_MTLC, **chain_record_fields(chains)})
    return records


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path, help="the run's folder (train.log, train/, eval/)")
    parser.add_argument(
        "--eval-dir",
        type=Path,
        default=None,
        help="the evaluation to record (default: RUN_DIR/eval; e.g. RUN_DIR/eval_seed2000 for other seeds)",
    )
    data = parser.add_mutually_exclusive_group(required=True)
    data.add_argument("--dataset", type=Path, help="the LeRobotDataset root it trained on")
    data.add_argument(
        "--dataset-of",
        metavar="METHOD",
        help="take the data's size from METHOD's records in --setting (a run on the same data, whose "
        "dataset is no longer on this machine)",
    )
    parser.add_argument("--method", required=True, help="the record's method name, e.g. subgoalvla")
    parser.add_argument("--setting", choices=SETTINGS, required=True, help="the table the records belong to")
    parser.add_argument("--scene", required=True, help="procedural | calvin_D | metaworld")
    parser.add_argument("--commit", required=True, help="the git commit the run's code was at")
    for stage in ("data", "train", "eval"):
        parser.add_argument(f"--{stage}-command", required=True, help=f"the exact {stage} command")
    parser.add_argument(
        "--earlier-run",
        type=Path,
        action="append",
        default=[],
        help="a folder (train.log and train_config.json) of a lerobot-train run this policy was trained in "
        "before RUN_DIR's (repeat); its samples and training time are added",
    )
    parser.add_argument(
        "--note", default=None, help="what a reader must know about the run (its provenance note)"
    )
    args = parser.parse_args()
    if args.dataset is not None and not (args.dataset / "meta" / "info.json").is_file():
        raise SystemExit(
            f"--dataset {args.dataset}: no meta/info.json; pass the LeRobotDataset's root folder"
        )
    data_size = (
        dataset_size(args.dataset)
        if args.dataset is not None
        else dataset_size_of(args.dataset_of, args.setting, load_records())
    )
    provenance = {
        "method": args.method,
        "setting": args.setting,
        "scene": args.scene,
        "commit": args.commit,
        "code_era": code_era(args.commit),
        "data_command": args.data_command,
        "train_command": args.train_command,
        "eval_command": args.eval_command,
        **({"provenance": args.note} if args.note else {}),
    }
    if args.eval_dir is not None and not args.eval_dir.is_dir():
        raise SystemExit(f"--eval-dir {args.eval_dir}: no such folder; pass the folder of the tasks' results")
    records = records_from_run(args.run_dir, data_size, provenance, args.eval_dir, args.earlier_run)
    store_records(records)  # replaces the records of the same run (e.g. one evaluated again)
    for r in records:
        print(f"{r['method']} {r['setting']:<14} {r['task']:<24} {r['successes']}/{r['episodes']}")


if __name__ == "__main__":
    main()
