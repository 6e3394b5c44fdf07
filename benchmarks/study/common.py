"""Shared plumbing of the study (docs/RESULTS.md): data, training, evaluation and the results file.

Every table of the study is a list of *runs*; a run is (method, setting, task, seed) with a training command,
an evaluation and one record per evaluated task in ``benchmarks/study/results.json``. Everything goes through
the commands a user runs (``subgoalvla-generate-calvin``, ``subgoalvla-convert-calvin``, ``lerobot-train``,
``lerobot-eval``) in subprocesses, with one thread each (``OMP_NUM_THREADS=1``: 2-core machines oversubscribe
otherwise). A run whose records are already in the results file is skipped, a finished dataset or checkpoint
is reused, so an interrupted study resumes where it stopped; asking for more evaluation episodes than a record
has continues its evaluation from the next seed. The results file is rewritten atomically.

Record keys (the issue's contract): ``method``, ``setting`` (single_task | multi_task | lh_mtlc), ``task``,
``seed``, ``episodes``, ``successes`` (+ ``avg_len`` for lh_mtlc), ``train_samples``, ``train_seconds``,
``scene``; plus ``samples_per_s``, ``train_episodes`` and ``train_frames``, ``eval_seconds`` and
``eval_seconds_per_episode`` (wall time, policy and simulator together), ``chain_sr`` (LH-1..5, lh_mtlc),
``machine``, and where it came from (``records.PROVENANCE_KEYS``: the commit, its code era, the exact data,
train and eval commands). ``RunSpec.chains`` adds an lh_mtlc record per run.
"""

from __future__ import annotations

import json
import logging
import os
import platform
import shlex
import subprocess
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from records import (
    RESULTS_PATH,
    chain_record_fields,
    code_era,
    eval_time_fields,
    load_records,
    record_key,
    store_records,
)

from lerobot_subgoalvla.calvin_vocab import FIXTURE_TASKS  # noqa: F401 - the study's task list, re-exported

logger = logging.getLogger("study")

#: The setting and task name of a record of CALVIN's long-horizon benchmark (chains of five subtasks).
LH_MTLC = "lh_mtlc"
#: Evaluation seeds start here; the generator's data seeds are small integers, so the start states differ.
EVAL_SEED = 1000
SCENE = "procedural"


def _env() -> dict[str, str]:
    return {
        **os.environ,
        "OMP_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "HF_HUB_OFFLINE": "1",
        "MPLBACKEND": "Agg",
    }


def run(command: Sequence[str], log_path: Path) -> float:
    """Run ``command`` with its output in ``log_path``; returns the wall time. Raises on a non-zero exit."""
    log_path.parent.mkdir(parents=True, exist_ok=True)
    logger.info("$ %s   (log: %s)", shlex.join(command), log_path)
    start = time.perf_counter()
    with log_path.open("a") as log:
        code = subprocess.call(list(command), stdout=log, stderr=subprocess.STDOUT, env=_env())
    if code != 0:
        raise RuntimeError(f"{command[0]} failed with exit {code}; see {log_path}")
    return time.perf_counter() - start


def code_commit() -> str:
    """The git commit the study's code is at, with ``+dirty`` when tracked files differ from it."""
    root = Path(__file__).resolve().parents[2]
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=True)
    status = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=no"], cwd=root, capture_output=True, text=True
    )
    return head.stdout.strip() + ("+dirty" if status.stdout.strip() else "")


def machine() -> str:
    """One line naming the machine the figures were measured on."""
    return f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, {platform.system()}"


@dataclass(frozen=True)
class DataSpec:
    """A generated + converted dataset: which tasks, how many attempts, image sizes."""

    name: str
    tasks: tuple[str, ...]
    num_tasks: int
    static_size: int = 200
    gripper_size: int = 84
    seed: int = 0
    #: A segment ends when none of ``tasks`` is feasible any more: a single task needs 1 (one attempt each).
    tasks_per_segment: int = 4

    def generate_command(self, work: Path, workers: int = 2) -> list[str]:
        """The ``subgoalvla-generate-calvin`` call that writes the native episodes."""
        return [
            "subgoalvla-generate-calvin",
            *("--output", str(work / "data" / f"{self.name}_native")),
            *("--num-tasks", str(self.num_tasks), "--seed", str(self.seed)),
            *("--tasks-per-segment", str(self.tasks_per_segment), "--workers", str(workers)),
            *("--tasks", ",".join(self.tasks)),
            *("--static-size", str(self.static_size), "--gripper-size", str(self.gripper_size)),
        ]

    def convert_command(self, work: Path, workers: int = 2) -> list[str]:
        """The ``subgoalvla-convert-calvin`` call that makes the LeRobotDataset."""
        native, root = work / "data" / f"{self.name}_native", work / "data" / self.name
        return ["subgoalvla-convert-calvin", str(native), "--repo-id", f"study/{self.name}",
                "--root", str(root), "--workers", str(workers)]  # fmt: skip

    def data_command(self, work: Path) -> str:
        """Both calls as one line: the ``data_command`` of a record."""
        return f"{shlex.join(self.generate_command(work))} && {shlex.join(self.convert_command(work))}"

    def prepare(self, work: Path, workers: int = 2) -> Path:
        """Generate and convert (each step skipped when done); returns the dataset root."""
        native, root = work / "data" / f"{self.name}_native", work / "data" / self.name
        if not (native / "training").is_dir():
            run(self.generate_command(work, workers), work / "logs" / f"{self.name}_generate.log")
        if not root.is_dir():
            resume = ["--resume"] if root.with_name(root.name + ".partial").is_dir() else []
            run([*self.convert_command(work, workers), *resume], work / "logs" / f"{self.name}_convert.log")
        return root


@dataclass(frozen=True)
class Method:
    """A policy as trained by ``lerobot-train``: its type and the flags that configure it."""

    name: str
    policy_flags: tuple[str, ...]
    batch_size: int = 32


def two_stage_flags(steps: int) -> tuple[str, ...]:
    """SubgoalVLA through both stages: stage II for the last fifth of ``steps``, as the demo does."""
    return (f"--policy.stage2_start_step={steps * 4 // 5}",)


@dataclass
class RunSpec:
    """One training run and the tasks it is evaluated on."""

    method: Method
    setting: str
    data: DataSpec
    eval_tasks: tuple[str, ...]
    seed: int
    steps: int
    episodes: int
    extra_train_flags: tuple[str, ...] = field(default_factory=tuple)
    #: An existing converted dataset of ``data``'s content (e.g. the demo's); generated when None.
    dataset_root: Path | None = None
    #: Episodes stepped together by ``lerobot-eval`` (more than one runs them in async env workers).
    eval_batch_size: int = 1
    #: LH-MTLC chains evaluated after the tasks (CALVIN's chains 0 .. chains - 1); 0: none.
    chains: int = 0

    @property
    def run_name(self) -> str:
        return f"{self.setting}-{self.method.name}-{self.data.name}-s{self.seed}"


def _previous(spec: RunSpec, records: list[dict], work: Path) -> dict[str, dict]:
    """Task -> the record this run already has in ``records`` (on the same data, where it exists already)."""
    samples = spec.steps * spec.method.batch_size
    root = spec.dataset_root or work / "data" / spec.data.name
    frames = dataset_size(root)["train_frames"] if (root / "meta" / "info.json").is_file() else None
    wanted = {
        (spec.method.name, setting, task, spec.seed, samples, frames)
        for task, (setting, _) in _targets(spec).items()
    }
    return {r["task"]: r for r in records if record_key(r) in wanted}


def _targets(spec: RunSpec) -> dict[str, tuple[str, int]]:
    """Task -> (setting, episodes) of the records this run must hold: every task, then its chains."""
    targets = dict.fromkeys(spec.eval_tasks, (spec.setting, spec.episodes))
    if spec.chains:
        targets[LH_MTLC] = (LH_MTLC, spec.chains)
    return targets


def _done(spec: RunSpec, previous: dict[str, dict]) -> bool:
    return all(
        task in previous and previous[task]["episodes"] >= episodes
        for task, (_, episodes) in _targets(spec).items()
    )


def _evaluations(spec: RunSpec, checkpoint: Path, out: Path) -> dict[str, dict]:
    """Task -> its evaluation fields: every task of ``spec``, then its LH-MTLC chains (if any)."""
    results = {task: _evaluate(spec, task, checkpoint, out) for task in spec.eval_tasks}
    if spec.chains:
        results[LH_MTLC] = _evaluate_chains(spec, checkpoint, out)
    return results


def _last_train_metrics(log_path: Path) -> dict[str, float]:
    from lerobot_subgoalvla.demo_report import parse_train_log

    records = parse_train_log(log_path)
    return records[-1] if records else {}


def _checkpoint(out: Path) -> Path:
    return out / "train" / "checkpoints" / "last" / "pretrained_model"


def execute(spec: RunSpec, work: Path, results_path: Path = RESULTS_PATH) -> list[dict]:
    """Train (or reuse the checkpoint), evaluate every task, store and return the records.

    A run recorded with fewer episodes than ``spec.episodes`` continues its evaluation from the next seed with
    the same checkpoint, also for a run recorded from its folder (``import_run.py``) that still exists.
    """
    previous = _previous(spec, load_records(results_path), work)
    if _done(spec, previous):
        logger.info("%s: already in %s, skipped", spec.run_name, results_path)
        return []
    source = next((Path(r["source"]) for r in previous.values() if r.get("source")), None)
    if source is not None and _checkpoint(source).is_dir():
        logger.info("%s: continuing the evaluation of %s", spec.run_name, source)
        training = {k: v for k, v in next(iter(previous.values())).items() if k not in _EVALUATION_KEYS}
        records = [
            {**training, **previous.get(task, {}), "setting": _targets(spec)[task][0], "task": task, **fields}
            for task, fields in _evaluations(spec, _checkpoint(source), source).items()
        ]
        store_records(records, results_path)
        return records
    root = spec.dataset_root or spec.data.prepare(work)
    size = dataset_size(root)
    # The frame count in the folder's name: a checkpoint is never reused for another generation of the data.
    out = work / "runs" / f"{spec.run_name}-{size['train_frames']}f"
    train_log = out / "train.log"
    timing = out / "train_seconds.txt"
    train_command = [
        "lerobot-train",
        *spec.method.policy_flags,
        "--policy.push_to_hub=false",
        f"--dataset.repo_id=study/{spec.data.name}",
        f"--dataset.root={root}",
        "--dataset.video_backend=pyav",
        f"--output_dir={out / 'train'}",
        f"--steps={spec.steps}",
        f"--batch_size={spec.method.batch_size}",
        "--num_workers=1",
        "--log_freq=50",
        f"--save_freq={spec.steps}",
        f"--seed={spec.seed}",
        "--wandb.enable=false",
        *spec.extra_train_flags,
    ]
    if not timing.is_file():
        if (out / "train").exists():
            import shutil

            shutil.rmtree(out / "train")  # an interrupted run restarts: its seconds would not add up
        timing.parent.mkdir(parents=True, exist_ok=True)
        timing.write_text(f"{run(train_command, train_log):.1f}\n")
    metrics = _last_train_metrics(train_log)
    commit = code_commit()
    training = {
        "train_samples": spec.steps * spec.method.batch_size,
        "train_seconds": round(float(timing.read_text()), 1),
        "samples_per_s": metrics.get("smp/s"),
        **size,
        "scene": SCENE,
        "machine": machine(),
        "commit": commit,
        "code_era": code_era(commit),
        "data_command": spec.data.data_command(work) if spec.dataset_root is None else f"given: {root}",
        "train_command": shlex.join(train_command),
    }
    records = [
        {
            "method": spec.method.name,
            "setting": _targets(spec)[task][0],
            "task": task,
            "seed": spec.seed,
            **fields,
            **training,
        }
        for task, fields in _evaluations(spec, _checkpoint(out), out).items()
    ]
    store_records(records, results_path)
    return records


#: A record's keys that belong to its evaluation, not to its training run.
_EVALUATION_KEYS = frozenset(
    ("setting", "task", "episodes", "successes", "avg_len", "chain_sr")
    + ("eval_seconds", "eval_seconds_per_episode")
)


def dataset_size(root: Path) -> dict[str, int]:
    """``train_episodes`` and ``train_frames`` of a LeRobotDataset (they tell regenerated data apart)."""
    info = json.loads((root / "meta" / "info.json").read_text())
    return {"train_episodes": info["total_episodes"], "train_frames": info["total_frames"]}


def _eval_command(
    spec: RunSpec, checkpoint: Path, task: str, out: Path, done: int = 0, first_seed: int = EVAL_SEED
) -> list[str]:
    """The ``lerobot-eval`` call for the episodes of ``task`` after the first ``done``."""
    return [
        "lerobot-eval",
        f"--policy.path={checkpoint}",
        "--env.type=calvin",
        f"--env.task={task}",
        f"--env.static_image_size={spec.data.static_size}",
        f"--env.gripper_image_size={spec.data.gripper_size}",
        f"--eval.n_episodes={spec.episodes - done}",
        f"--eval.batch_size={spec.eval_batch_size}",
        f"--eval.use_async_envs={str(spec.eval_batch_size > 1).lower()}",
        f"--output_dir={out}",
        f"--seed={first_seed}",
    ]


def _evaluate(spec: RunSpec, task: str, checkpoint: Path, out: Path) -> dict:
    """``spec.episodes`` episodes of ``task`` from seed ``EVAL_SEED`` on (episode i starts from seed
    ``EVAL_SEED + i``, as ``lerobot-eval`` seeds them), in blocks: a finished shorter evaluation
    (``eval/<task>/``) is kept and continued in ``eval/<task>_from_seed<S>/``."""
    from lerobot_subgoalvla.demo_report import episode_successes

    successes: list[bool] = []
    commands: list[str] = []
    seconds = 0.0
    while len(successes) < spec.episodes:
        first_seed = EVAL_SEED + len(successes)
        name = f"{task}_from_seed{first_seed}" if successes else task
        eval_dir = out / "eval" / name
        command = _eval_command(spec, checkpoint, task, eval_dir, len(successes), first_seed)
        commands.append(shlex.join(command))
        if not (eval_dir / "eval_info.json").is_file():
            run(command, out / f"eval_{name}.log")
        info = json.loads((eval_dir / "eval_info.json").read_text())
        block = episode_successes(info)
        if not block:
            raise RuntimeError(f"{eval_dir}/eval_info.json holds no episodes: delete {eval_dir} to rerun it")
        successes += block
        seconds += info["overall"]["eval_s"]
    return {
        "episodes": len(successes),
        "successes": sum(successes),
        **eval_time_fields(seconds, len(successes)),
        "eval_command": " && ".join(commands),
    }


def _evaluate_chains(spec: RunSpec, checkpoint: Path, out: Path) -> dict:
    """CALVIN's chains ``0 .. spec.chains - 1``, one after the other, appended to
    ``eval/lh_mtlc/results.jsonl`` (the demo's layout); a file with fewer chains is continued
    (``--env.resume``: the chains it holds are skipped), so 20 chains of a demo grow to 100 with the same
    checkpoint. The time is ``lerobot-eval``'s over the finished blocks (``eval_info.json`` of each)."""
    from lerobot_subgoalvla.envs.calvin.evaluation.results import read_episode_results

    results = out / "eval" / LH_MTLC / "results.jsonl"
    have = len(read_episode_results(results)) if results.is_file() else 0
    command = [
        "lerobot-eval",
        f"--policy.path={checkpoint}",
        "--env.type=calvin",
        f"--env.task={LH_MTLC}",
        f"--env.chain_stop={spec.chains}",
        f"--env.results_path={results}",
        "--env.resume=true",  # chains already in the results file are skipped
        f"--env.static_image_size={spec.data.static_size}",
        f"--env.gripper_image_size={spec.data.gripper_size}",
        "--eval.n_episodes=1",
        "--eval.batch_size=1",
        "--eval.use_async_envs=false",
        "--seed=0",
    ]
    if have < spec.chains:
        name = f"{LH_MTLC}_chains{have}-{spec.chains}"
        run([*command, f"--output_dir={out / 'eval' / name}"], out / f"eval_{name}.log")
    fields = chain_record_fields(results)
    infos = [
        out / "eval" / LH_MTLC / "eval_info.json",
        *(out / "eval").glob(f"{LH_MTLC}_chains*/eval_info.json"),
        *(out / "eval" / LH_MTLC / "runs").glob("*/eval_info.json"),  # scripts/demo.sh's continuations
    ]
    seconds = sum(json.loads(info.read_text())["overall"]["eval_s"] for info in infos if info.is_file())
    return {
        **fields,
        **eval_time_fields(seconds, fields["episodes"]),
        "eval_command": shlex.join(command),
    }
