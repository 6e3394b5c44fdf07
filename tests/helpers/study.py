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
    """Yield ``benchmarks/study/<name>.py`` imported, then forget it (a fixture's body: ``yield from``)."""
    monkeypatch.syspath_prepend(str(STUDY))
    yield importlib.import_module(name)
    sys.modules.pop(name, None)
