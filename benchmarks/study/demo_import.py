"""Records of a finished ``scripts/demo.sh`` run, so the study does not train the demo's run twice."""

from __future__ import annotations

from pathlib import Path

from common import LH_MTLC, SCENE, dataset_size, machine
from records import chain_record_fields


def records_from_demo(demo_dir: Path, method: str, seed: int, batch_size: int) -> list[dict]:
    """Records of a finished ``scripts/demo.sh`` run (its ``train.log``, ``eval/<task>/`` and
    ``eval/lh_mtlc/``).

    The demo is the multi-task SubgoalVLA run of this study; importing it avoids training the same run twice.
    """
    from lerobot_subgoalvla.demo_report import parse_train_log, read_task_results, train_wall_seconds

    log = parse_train_log(demo_dir / "train.log")
    if not log:
        raise ValueError(f"{demo_dir / 'train.log'} has no lerobot-train step lines")
    steps = int(log[-1]["step"])
    seconds = train_wall_seconds(demo_dir / "train.log")
    dataset = demo_dir / "dataset"
    size = dataset_size(dataset) if (dataset / "meta" / "info.json").is_file() else {}
    training = {
        "method": method,
        "seed": seed,
        "train_samples": steps * batch_size,
        "train_episodes": size.get("train_episodes"),
        "train_frames": size.get("train_frames"),
        "train_seconds": None if seconds is None else round(seconds, 1),
        "samples_per_s": log[-1].get("smp/s"),
        "scene": SCENE,
        "machine": machine(),
        "source": str(demo_dir),
    }
    records = [
        {
            **training,
            "setting": "multi_task",
            "task": task,
            "episodes": r["episodes"],
            "successes": r["successes"],
        }
        for task, r in read_task_results(demo_dir / "eval").items()
    ]
    chains = demo_dir / "eval" / LH_MTLC / "results.jsonl"
    if chains.is_file():
        records.append({**training, "setting": LH_MTLC, "task": LH_MTLC, **chain_record_fields(chains)})
    return records
