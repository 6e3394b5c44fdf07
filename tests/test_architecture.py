"""The dependency rules of docs/architecture.md: import direction, light modules, no cycles, module size."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "lerobot_subgoalvla"
ROOT = "lerobot_subgoalvla"
CALVIN = f"{ROOT}.envs.calvin"


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, top_level_only: bool) -> set[str]:
    """Absolute names this file imports (``from a import b`` gives ``a`` and ``a.b``)."""
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    names: set[str] = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


MODULES = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _project_imports(module: str, top_level_only: bool = False) -> set[str]:
    return {name for name in _imports(MODULES[module], top_level_only) if name in MODULES and name != module}


#: part -> prefixes it must not import (lazily or not)
FORBIDDEN = {
    f"{CALVIN}.sim": (
        f"{CALVIN}.oracle",
        f"{CALVIN}.evaluation",
        f"{CALVIN}.expert",
        f"{CALVIN}.env",
        f"{CALVIN}.vector",
        f"{CALVIN}.configs",
        f"{ROOT}.policies",
        f"{ROOT}.datasets_conversion",
    ),
    f"{CALVIN}.oracle": (
        f"{CALVIN}.sim",
        f"{CALVIN}.evaluation",
        f"{CALVIN}.expert",
        f"{CALVIN}.env",
        f"{ROOT}.policies",
    ),
    f"{CALVIN}.evaluation": (
        f"{CALVIN}.sim",
        f"{CALVIN}.expert",
        f"{CALVIN}.env",
        f"{CALVIN}.configs",
        f"{ROOT}.policies",
    ),
    f"{CALVIN}.expert": (f"{CALVIN}.env", f"{CALVIN}.vector", f"{CALVIN}.configs", f"{ROOT}.policies"),
    f"{ROOT}.envs": (f"{ROOT}.policies", f"{ROOT}.visualization", f"{ROOT}.plugin"),
    # the policy knows nothing of CALVIN beyond what a dataset or env tells it, and not the conversion package
    f"{ROOT}.policies": (
        f"{ROOT}.envs",
        f"{ROOT}.visualization",
        f"{ROOT}.plugin",
        f"{ROOT}.datasets_conversion",
        f"{ROOT}.metaworld",
        f"{ROOT}.calvin_vocab",
        f"{ROOT}.contract.calvin",
    ),
    # the contract is the bottom layer: it imports nothing else of the project
    f"{ROOT}.contract": tuple(
        f"{ROOT}.{part}"
        for part in (
            "policies",
            "envs",
            "datasets_conversion",
            "visualization",
            "metaworld",
            "plugin",
            "calvin_vocab",
        )
    ),
    f"{ROOT}.datasets_conversion": (f"{ROOT}.policies", f"{ROOT}.visualization"),
}
#: modules that env workers and the light commands import: no heavy library at module level
LIGHT = [m for m in MODULES if m.startswith((f"{CALVIN}.sim", f"{CALVIN}.oracle", f"{CALVIN}.evaluation",
                                             f"{CALVIN}.expert"))]  # fmt: skip
LIGHT += [ROOT, f"{ROOT}.envs", CALVIN, f"{CALVIN}.env", f"{CALVIN}.vector", f"{CALVIN}.protocol"]
LIGHT += [m for m in MODULES if m.startswith(f"{ROOT}.contract")]
HEAVY = ("torch", "transformers", "lerobot", "diffusers", "matplotlib")


@pytest.mark.parametrize("part", list(FORBIDDEN))
def test_imports_go_one_way(part: str) -> None:
    bad = {
        (module, name)
        for module in MODULES
        if module == part or module.startswith(part + ".")
        for name in _project_imports(module)
        if any(name == f or name.startswith(f + ".") for f in FORBIDDEN[part])
    }
    assert not bad, f"{part} must not import these (docs/architecture.md): {sorted(bad)}"


def test_light_modules_import_no_heavy_library_at_module_level() -> None:
    bad = {
        (module, name)
        for module in LIGHT
        for name in _imports(MODULES[module], top_level_only=True)
        if name.split(".")[0] in HEAVY
    }
    assert not bad, f"import these lazily (inside the function that needs them): {sorted(bad)}"


def test_no_import_cycle_between_modules() -> None:
    """No cycle, counting imports inside functions too (a lazy import is still a dependency)."""
    graph = {m: _project_imports(m) for m in MODULES}
    # a package's __init__ is imported before its submodules: importing it is not a use of them
    graph = {m: {n for n in deps if not m.startswith(n + ".")} for m, deps in graph.items()}
    state: dict[str, int] = {}

    def visit(module: str, path: list[str]) -> None:
        state[module] = 1
        for dep in graph[module]:
            if state.get(dep) == 1:
                raise AssertionError("import cycle: " + " -> ".join([*path[path.index(dep) :], dep]))
            if dep not in state:
                visit(dep, [*path, dep])
        state[module] = 2

    for module in graph:
        if module not in state:
            visit(module, [module])


def test_modules_stay_under_400_lines() -> None:
    long = {m: n for m, p in MODULES.items() if (n := len(p.read_text().splitlines())) > 400}
    assert not long, f"split these modules (one concern per file, < 400 lines): {long}"
