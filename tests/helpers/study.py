"""Import a module of ``benchmarks/study`` (a folder of scripts, not a package) for one test."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import pytest

STUDY = Path(__file__).resolve().parents[2] / "benchmarks" / "study"


def study_module(monkeypatch: pytest.MonkeyPatch, name: str) -> Iterator[ModuleType]:
    """Yield ``benchmarks/study/<name>.py`` imported, then forget every study module the test imported (a
    fixture's body: ``yield from``), so that the next test imports them afresh."""
    monkeypatch.syspath_prepend(str(STUDY))
    before = set(sys.modules)
    yield importlib.import_module(name)
    for module in set(sys.modules) - before:
        if Path(getattr(sys.modules[module], "__file__", None) or "/").parent == STUDY:
            sys.modules.pop(module)
