"""The study's results file: records replace their earlier versions, a shorter evaluation is continued, every
record says where it came from, and a finished scripts/*.sh run is recorded with its commit and commands."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from helpers.study import STUDY, study_module


@pytest.fixture
def common(monkeypatch: pytest.MonkeyPatch):
    yield from study_module(monkeypatch, "common")


def _record(task: str, successes: int, episodes: int, samples: int = 80000, **extra) -> dict:
    return {
        "method": "subgoalvla",
        "setting": "multi_task",
        "task": task,
        "seed": 0,
        "episodes": episodes,
        "successes": successes,
        "train_samples": samples,
        **extra,
    }


def _write_eval(eval_dir: Path, successes: list[bool]) -> None:
    eval_dir.mkdir(parents=True)
    info = {"per_task": [{"metrics": {"successes": successes}}], "overall": {"eval_s": 2.0 * len(successes)}}
    (eval_dir / "eval_info.json").write_text(json.dumps(info))


def test_a_stored_record_replaces_its_earlier_version_only(common, tmp_path: Path) -> None:
    path = tmp_path / "results.json"
    common.store_records([_record("open_drawer", 5, 10), _record("open_drawer", 9, 10, samples=96000)], path)
    common.store_records([_record("open_drawer", 12, 20)], path)
    stored = {(r["train_samples"], r["episodes"]): r["successes"] for r in common.load_records(path)}
    assert stored == {(96000, 10): 9, (80000, 20): 12}


def test_a_shorter_evaluation_continues_from_the_next_seed(common, tmp_path, monkeypatch) -> None:
    demo = tmp_path / "demo"  # a run imported from a demo folder: its checkpoint and first 10 episodes
    (demo / "train" / "checkpoints" / "last" / "pretrained_model").mkdir(parents=True)
    _write_eval(demo / "eval" / "open_drawer", [True] * 6 + [False] * 4)
    results = tmp_path / "results.json"
    common.store_records([_record("open_drawer", 6, 10, source=str(demo), train_seconds=60.0)], results)
    commands = []

    def fake_run(command, log_path):
        commands.append(command)
        flags = dict(arg[2:].split("=", 1) for arg in command[1:])
        _write_eval(Path(flags["output_dir"]), [True] * int(flags["eval.n_episodes"]))
        return 1.0

    monkeypatch.setattr(common, "run", fake_run)
    method = common.Method("subgoalvla", ("--policy.type=subgoalvla",))
    data = common.DataSpec("fixtures", ("open_drawer",), 240)
    spec = common.RunSpec(method, "multi_task", data, ("open_drawer",), 0, 2500, 20)
    (record,) = common.execute(spec, tmp_path / "work", results)
    assert len(commands) == 1 and "--seed=1010" in commands[0] and "--eval.n_episodes=10" in commands[0]
    assert (record["episodes"], record["successes"], record["train_seconds"]) == (20, 16, 60.0)
    assert common.load_records(results) == [record]
    assert common.execute(spec, tmp_path / "work", results) == []  # done: nothing is evaluated again
    assert len(commands) == 1


def _write_chains(results: Path, chain_ids: range, completed: int) -> None:
    results.parent.mkdir(parents=True, exist_ok=True)
    with results.open("a") as f:
        for chain_id in chain_ids:
            line = {"chain_id": chain_id, "tasks": ["open_drawer"] * 5, "num_completed": completed}
            f.write(json.dumps(line) + "\n")


def test_a_shorter_chain_evaluation_is_continued_to_the_asked_chains(common, tmp_path, monkeypatch) -> None:
    demo = tmp_path / "demo"  # a demo with its checkpoint, one task's 20 episodes and 2 of its chains
    (demo / "train" / "checkpoints" / "last" / "pretrained_model").mkdir(parents=True)
    _write_eval(demo / "eval" / "open_drawer", [True] * 20)
    _write_chains(demo / "eval" / "lh_mtlc" / "results.jsonl", range(2), completed=0)
    (demo / "eval" / "lh_mtlc" / "eval_info.json").write_text(json.dumps({"overall": {"eval_s": 10.0}}))
    results = tmp_path / "results.json"
    task_record = _record("open_drawer", 20, 20, source=str(demo), train_seconds=60.0)
    chain_record = {**task_record, "setting": "lh_mtlc", "task": "lh_mtlc", "episodes": 2, "successes": 0}
    common.store_records([task_record, {**chain_record, "avg_len": 0.0}], results)
    commands = []

    def fake_run(command, log_path):  # chains 2 and 3, both with every subtask done
        commands.append(command)
        flags = dict(arg[2:].split("=", 1) for arg in command[1:])
        _write_chains(Path(flags["env.results_path"]), range(2, int(flags["env.chain_stop"])), completed=5)
        (Path(flags["output_dir"]) / "eval_info.json").parent.mkdir(parents=True)
        (Path(flags["output_dir"]) / "eval_info.json").write_text(json.dumps({"overall": {"eval_s": 30.0}}))
        return 1.0

    monkeypatch.setattr(common, "run", fake_run)
    method = common.Method("subgoalvla", ("--policy.type=subgoalvla",))
    data = common.DataSpec("fixtures", ("open_drawer",), 240)
    spec = common.RunSpec(method, "multi_task", data, ("open_drawer",), 0, 2500, 20, chains=4)
    records = {r["task"]: r for r in common.execute(spec, tmp_path / "work", results)}
    assert len(commands) == 1 and "--env.chain_stop=4" in commands[0] and "--env.resume=true" in commands[0]
    chains = records["lh_mtlc"]
    assert (chains["setting"], chains["episodes"], chains["successes"]) == ("lh_mtlc", 4, 2)
    assert chains["avg_len"] == 2.5
    assert chains["chain_sr"]["1"] == 0.5 and chains["train_seconds"] == 60.0
    assert (chains["eval_seconds"], chains["eval_seconds_per_episode"]) == (40.0, 10.0)  # the demo's + new
    # The finished task evaluation is read, not rerun (the one command was the chains').
    assert (records["open_drawer"]["successes"], records["open_drawer"]["episodes"]) == (20, 20)
    assert common.execute(spec, tmp_path / "work", results) == [] and len(commands) == 1


def test_records_on_another_generation_of_the_data_are_not_this_runs(common, tmp_path: Path) -> None:
    root = tmp_path / "dataset"  # the same generator command, run again: other episodes, other frame count
    (root / "meta").mkdir(parents=True)
    (root / "meta" / "info.json").write_text(json.dumps({"total_episodes": 216, "total_frames": 16887}))
    method = common.Method("subgoalvla", ("--policy.type=subgoalvla",))
    data = common.DataSpec("fixtures", ("open_drawer",), 240)
    spec = common.RunSpec(method, "multi_task", data, ("open_drawer",), 0, 2500, 20, dataset_root=root)
    old, new = (_record("open_drawer", 15, 20, train_frames=frames) for frames in (16798, 16887))
    assert common._previous(spec, [old], tmp_path) == {}
    assert common._previous(spec, [old, new], tmp_path) == {"open_drawer": new}
    common.store_records([old], tmp_path / "results.json")
    common.store_records([new], tmp_path / "results.json")  # both kept: they are two runs
    assert len(common.load_records(tmp_path / "results.json")) == 2


def test_a_regenerated_dataset_trains_its_own_checkpoint(common, tmp_path, monkeypatch) -> None:
    commands = []

    def fake_run(command, log_path):
        commands.append(command)
        log_path.parent.mkdir(parents=True, exist_ok=True)
        log_path.touch()
        flags = dict(arg[2:].split("=", 1) for arg in command[1:])
        if command[0] == "lerobot-train":
            (Path(flags["output_dir"]) / "checkpoints" / "last" / "pretrained_model").mkdir(parents=True)
        else:
            _write_eval(Path(flags["output_dir"]), [True] * int(flags["eval.n_episodes"]))
        return 1.0

    monkeypatch.setattr(common, "run", fake_run)
    method = common.Method("subgoalvla", ("--policy.type=subgoalvla",))
    data = common.DataSpec("fixtures", ("open_drawer",), 240)
    results = tmp_path / "results.json"
    for frames in (16798, 16887, 16798):  # the third: the first run again, already recorded
        root = tmp_path / f"dataset{frames}"
        (root / "meta").mkdir(parents=True, exist_ok=True)
        (root / "meta" / "info.json").write_text(json.dumps({"total_episodes": 216, "total_frames": frames}))
        spec = common.RunSpec(method, "multi_task", data, ("open_drawer",), 0, 2500, 2, dataset_root=root)
        common.execute(spec, tmp_path / "work", results)
    trained = [
        next(a for a in c if a.startswith("--output_dir=")) for c in commands if c[0] == "lerobot-train"
    ]
    assert len(trained) == 2 and trained[0] != trained[1]
    assert sorted(r["train_frames"] for r in common.load_records(results)) == [16798, 16887]


def test_every_stored_record_says_where_it_came_from(common) -> None:
    import records

    results = records.load_records()
    assert results, "benchmarks/study/results.json holds no records"
    lacking = {
        f"{r['method']} {r['setting']} {r['task']} seed {r['seed']}": records.missing_provenance(r)
        for r in results
    }
    assert {name: missing for name, missing in lacking.items() if missing} == {}
    eras = {boundary for boundary, _ in records.ERA_COMMITS} | {records.FIRST_ERA, None}
    assert {r["code_era"] for r in results} <= eras


def test_a_record_without_a_command_needs_a_note(common) -> None:
    import records

    record = dict.fromkeys(records.PROVENANCE_KEYS, "x") | {"train_command": None, "recorded_in": "abc"}
    assert records.missing_provenance(record) == ["provenance (a note on the missing train_command)"]
    assert records.missing_provenance({**record, "provenance": "not recorded by the run's script"}) == []
    del record["recorded_in"]
    record["commit"] = None
    assert "commit or recorded_in" in records.missing_provenance({**record, "provenance": "note"})


def _git_has(*commits: str) -> bool:
    import subprocess

    root = STUDY.parents[1]
    return all(subprocess.run(["git", "cat-file", "-e", c], cwd=root, capture_output=True).returncode == 0
               for c in commits)  # fmt: skip


@pytest.mark.skipif(not _git_has("b6dfa55", "06900d6", "c27f484"), reason="needs the repository's history")
def test_the_code_era_is_the_last_era_commit_the_code_contains(common) -> None:
    import records

    assert records.code_era("ac54a9f") == records.FIRST_ERA  # the reference run's record, before both
    assert records.code_era("c27f484") == "b6dfa55"  # the fresh-machine demo run
    assert records.code_era("06900d6+dirty") == "06900d6"


def _fake_run(run: Path, tasks: dict[str, list[bool]], chains: int = 0) -> None:
    """A finished scripts/*.sh run: train.log, the last checkpoint's train_config.json, eval/<task>/."""
    step = "INFO ot_train.py:641 step:{step} smpl:1K ep:2 epch:0.1 loss:0.5 updt_s:0.4 data_s:0.1 smp/s:{sps}"
    log = [step.format(step=s, sps=sps) for s, sps in ((50, 40), (100, 61))]
    log.append("Training: 100%|##########| 100/100 [02:05<00:00,  0.8step/s]")
    checkpoint = run / "train" / "checkpoints" / "last" / "pretrained_model"
    checkpoint.mkdir(parents=True)
    (run / "train.log").write_text("\n".join(log) + "\n")
    (checkpoint / "train_config.json").write_text(json.dumps({"steps": 100, "batch_size": 8, "seed": 3}))
    for task, successes in tasks.items():
        _write_eval(run / "eval" / task, successes)
    if chains:
        _write_chains(run / "eval" / "lh_mtlc" / "results.jsonl", range(chains), completed=2)


_DATA_SIZE = {"train_episodes": 20, "train_frames": 1679}


def test_a_finished_run_is_recorded_with_its_commit_commands_and_counts(common, tmp_path: Path) -> None:
    import import_run
    import records as study_records

    run = tmp_path / "mt10" / "subgoalvla"
    _fake_run(run, {"reach-v3": [True] * 9 + [False], "push-v3": [False] * 10})
    provenance = {
        "method": "subgoalvla", "setting": "metaworld_mt10", "scene": "metaworld", "commit": "abc1234",
        "code_era": "06900d6", "data_command": "record", "train_command": "train", "eval_command": "eval",
    }  # fmt: skip
    records = import_run.records_from_run(run, _DATA_SIZE, provenance)
    by_task = {r["task"]: r for r in records}
    assert sorted(by_task) == ["push-v3", "reach-v3"]
    assert (by_task["reach-v3"]["successes"], by_task["reach-v3"]["episodes"]) == (9, 10)
    assert (by_task["push-v3"]["successes"], by_task["push-v3"]["episodes"]) == (0, 10)
    for record in records:
        assert {k: record[k] for k in provenance} == provenance
        assert record["source"] == str(run)
        assert (record["seed"], record["train_samples"]) == (3, 800)  # from train_config.json: 100 x 8
        assert (record["train_episodes"], record["train_frames"]) == (20, 1679)
        assert (record["train_seconds"], record["samples_per_s"]) == (125, 61)  # tqdm's 02:05, the last line
        assert record["eval_seconds"] == 20.0
        assert record["eval_seconds_per_episode"] == 2.0  # what the tables' eval s/ep column reads
        assert study_records.missing_provenance(record) == []


def test_a_finished_calvin_run_adds_its_chain_record(common, tmp_path: Path) -> None:
    import import_run
    import records as study_records

    run = tmp_path / "demo"
    _fake_run(run, {"open_drawer": [True] * 10}, chains=4)
    provenance = dict.fromkeys(study_records.PROVENANCE_KEYS, "x") | {
        "method": "subgoalvla", "setting": "multi_task", "scene": "procedural",
    }  # fmt: skip
    records = import_run.records_from_run(run, _DATA_SIZE, provenance)
    chains = next(r for r in records if r["task"] == "lh_mtlc")
    assert (chains["setting"], chains["episodes"], chains["avg_len"]) == ("lh_mtlc", 4, 2.0)
    assert chains["commit"] == "x" and chains["train_command"] == "x"
    assert [study_records.missing_provenance(r) for r in records] == [[], []]


def test_an_evaluation_on_other_seeds_is_recorded_from_its_own_folder(common, tmp_path: Path) -> None:
    import import_run

    run = tmp_path / "mt10" / "subgoalvla"
    _fake_run(run, {"reach-v3": [True] * 10})
    _write_eval(run / "eval_seed2000" / "reach-v3", [True, False, False])
    provenance = {"method": "subgoalvla", "setting": "metaworld_mt10_heldout"}
    (record,) = import_run.records_from_run(run, _DATA_SIZE, provenance, run / "eval_seed2000")
    assert (record["setting"], record["successes"], record["episodes"]) == ("metaworld_mt10_heldout", 1, 3)
    assert record["seed"] == 3  # the training seed, as for the run's other records


def test_a_run_that_never_logged_a_step_is_refused(common, tmp_path: Path) -> None:
    import import_run

    run = tmp_path / "run"
    _fake_run(run, {"reach-v3": [True]})
    (run / "train.log").write_text("Training:   0%|          | 0/100\n")
    with pytest.raises(SystemExit, match="no lerobot-train step lines"):
        import_run.records_from_run(run, _DATA_SIZE, {})


def test_a_kept_run_is_recorded_from_its_pretrained_model_folder(common, tmp_path: Path) -> None:
    import import_run

    run = tmp_path / "kept"
    _fake_run(run, {"reach-v3": [True, False]})
    (run / "train").rename(tmp_path / "moved")  # benchmarks/study/runs/ keeps pretrained_model/ at the top
    (tmp_path / "moved" / "checkpoints" / "last" / "pretrained_model").rename(run / "pretrained_model")
    (record,) = import_run.records_from_run(run, _DATA_SIZE, {})
    assert (record["seed"], record["train_samples"], record["successes"]) == (3, 800, 1)
    (run / "pretrained_model" / "train_config.json").unlink()
    with pytest.raises(SystemExit, match="train_config.json is missing"):
        import_run.records_from_run(run, _DATA_SIZE, {})


def test_a_policy_trained_over_several_runs_counts_the_earlier_ones(common, tmp_path: Path) -> None:
    import import_run

    run = tmp_path / "continued"
    _fake_run(run, {"reach-v3": [True]})
    earlier = tmp_path / "first_cycle"  # an earlier run keeps its train.log and train_config.json only
    _fake_run(earlier, {})
    (earlier / "train" / "checkpoints" / "last" / "pretrained_model" / "train_config.json").rename(
        earlier / "train_config.json"
    )
    (record,) = import_run.records_from_run(run, _DATA_SIZE, {}, earlier_runs=[earlier])
    assert (record["train_samples"], record["train_seconds"]) == (1600, 250)  # 2 x 800 samples, 2 x 125 s
    assert record["samples_per_s"] == 61  # the last run's
    (earlier / "train.log").write_text("no step lines\n")
    with pytest.raises(SystemExit, match="first_cycle/train.log has no lerobot-train step lines"):
        import_run.records_from_run(run, _DATA_SIZE, {}, earlier_runs=[earlier])


def test_the_data_size_comes_from_a_run_on_the_same_data(common) -> None:
    import import_run

    def stored(method: str, episodes: int, frames: int, setting: str = "metaworld_mt10") -> dict:
        return {"method": method, "setting": setting, "train_episodes": episodes, "train_frames": frames}

    records = [
        stored("a", 300, 23369),
        stored("a", 300, 23369),
        stored("a", 9, 9, "multi_task"),
        stored("b", 1, 2),
    ]
    assert import_run.dataset_size_of("a", "metaworld_mt10", records) == {
        "train_episodes": 300, "train_frames": 23369,
    }  # fmt: skip
    held_out = import_run.dataset_size_of("a", "metaworld_mt10_heldout", records)  # its runs, other seeds
    assert held_out == {"train_episodes": 300, "train_frames": 23369}
    with pytest.raises(SystemExit, match="--dataset-of c: none among its metaworld_mt10 records"):
        import_run.dataset_size_of("c", "metaworld_mt10", records)
    with pytest.raises(SystemExit, match="2 different sizes"):
        import_run.dataset_size_of("a", "metaworld_mt10", [*records, stored("a", 150, 11343)])
