"""The paired comparison of two evaluations: episodes pair by index, only the discordant ones count, and the
exact McNemar p-values are the binomial ones."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from helpers.study import study_module


@pytest.fixture
def paired(monkeypatch: pytest.MonkeyPatch):
    yield from study_module(monkeypatch, "paired")


def _eval(root: Path, outcomes: dict[str, str]) -> Path:
    """An evaluation folder: one eval_info.json per task, ``"1001"`` = episodes 0 and 3 solved."""
    for task, flags in outcomes.items():
        info = {"per_task": [{"task_group": task, "metrics": {"successes": [c == "1" for c in flags]}}]}
        (root / task).mkdir(parents=True)
        (root / task / "eval_info.json").write_text(json.dumps(info))
    return root


def test_exact_p_values(paired) -> None:
    assert paired.mcnemar_exact(0, 0) == 1.0
    assert paired.mcnemar_exact(4, 0) == pytest.approx(0.125)
    assert paired.mcnemar_exact(20, 5) == pytest.approx(0.00408, abs=5e-5)
    assert paired.mcnemar_exact(3, 3) == 1.0


def test_only_discordant_episodes_count_and_shared_tasks_pair(paired, tmp_path: Path, capsys) -> None:
    a = _eval(tmp_path / "a", {"push": "1100", "reach": "0000", "door": "1111"})
    b = _eval(tmp_path / "b", {"push": "1010", "reach": "0001"})
    rows = paired.pair(paired.read_successes(a), paired.read_successes(b))
    assert [(r.task, r.successes_a, r.successes_b, r.only_a, r.only_b) for r in rows] == [
        ("push", 2, 2, 1, 1),
        ("reach", 0, 1, 0, 1),
    ]
    assert paired.main([str(a), str(b), "--names", "conv", "patch"]) == 0
    out = capsys.readouterr().out
    assert "| all shared tasks | 8 | 2 | 3 | 1 | 2 | 1 |" in out
    assert "only conv" in out


def test_unequal_episode_counts_and_missing_folders_are_refused(paired, tmp_path: Path) -> None:
    a = _eval(tmp_path / "a", {"push": "110"})
    b = _eval(tmp_path / "b", {"push": "1100"})
    with pytest.raises(SystemExit) as stopped:
        paired.main([str(a), str(b)])
    assert stopped.value.code == 1
    with pytest.raises(ValueError, match="same --eval.n_episodes"):
        paired.pair(paired.read_successes(a), paired.read_successes(b))
    with pytest.raises(FileNotFoundError, match="no such evaluation folder"):
        paired.read_successes(tmp_path / "missing")
