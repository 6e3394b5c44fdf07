"""Meta-World task names, the named task sets, and the lookups a recording needs (docs/metaworld.md).

The names, instructions, ids and expert classes are LeRobot's own (``lerobot/envs/metaworld_config.json``,
shipped with LeRobot 0.6.1), so a generated dataset uses exactly the strings ``lerobot-eval
--env.type=metaworld`` hands a policy: ``task`` is the env's ``task_description`` (e.g. ``"Open a drawer"``
for ``drawer-open-v3``), as in LeRobot's published ``lerobot/metaworld_mt50``.

Name checks read that JSON file directly, so they answer without importing torch, LeRobot or Meta-World.
"""

from __future__ import annotations

import difflib
import functools
import importlib.metadata
import importlib.util
import json
from pathlib import Path
from typing import Any

#: Meta-World's MT10 benchmark (Yu et al. 2019, table 1), as LeRobot names the v3 envs.
MT10: tuple[str, ...] = (
    "reach-v3",
    "push-v3",
    "pick-place-v3",
    "door-open-v3",
    "drawer-open-v3",
    "drawer-close-v3",
    "button-press-topdown-v3",
    "peg-insert-side-v3",
    "window-open-v3",
    "window-close-v3",
)
#: Named sets ``--tasks`` accepts besides task names.
TASK_SETS: dict[str, tuple[str, ...]] = {"mt10": MT10}
#: What to tell a user whose environment cannot run Meta-World.
INSTALL_HINT = "pip install -e '.[metaworld]'"


@functools.cache
def _lerobot_metaworld_config() -> dict[str, Any]:
    """LeRobot's ``metaworld_config.json`` (names, instructions, ids, experts), read without imports."""
    spec = importlib.util.find_spec("lerobot")
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError(f"LeRobot is not installed; {INSTALL_HINT}")
    path = Path(next(iter(spec.submodule_search_locations))) / "envs" / "metaworld_config.json"
    if not path.is_file():
        raise RuntimeError(f"{path} is missing: this LeRobot has no Meta-World env; {INSTALL_HINT}")
    return json.loads(path.read_text())


def known_tasks() -> tuple[str, ...]:
    """All Meta-World task names LeRobot's env accepts (50, each with the ``-v3`` suffix)."""
    return tuple(_lerobot_metaworld_config()["TASK_DESCRIPTIONS"])


def check_task(name: str) -> str:
    """Return ``name`` if LeRobot's Meta-World env knows it; ValueError naming the closest ones otherwise."""
    known = known_tasks()
    if name in known:
        return name
    hint = difflib.get_close_matches(name if name.endswith("-v3") else f"{name}-v3", known, n=3)
    suggestion = f"; did you mean {', '.join(hint)}?" if hint else ""
    raise ValueError(
        f"unknown Meta-World task {name!r} (names end in -v3, e.g. drawer-open-v3; sets: "
        f"{', '.join(TASK_SETS)}){suggestion}"
    )


def parse_tasks(text: str) -> tuple[str, ...]:
    """``"mt10"`` or ``"reach-v3,drawer-open-v3"`` (sets and names may mix) -> names, first-seen order."""
    names: list[str] = []
    for item in (part.strip() for part in text.split(",")):
        if item:
            names.extend(TASK_SETS[item.lower()] if item.lower() in TASK_SETS else (check_task(item),))
    if not names:
        raise ValueError("--tasks needs at least one Meta-World task name or set (e.g. reach-v3 or mt10)")
    return tuple(dict.fromkeys(names))


def task_description(task: str) -> str:
    """The instruction LeRobot's env gives the policy, and the dataset's ``task`` string."""
    return _lerobot_metaworld_config()["TASK_DESCRIPTIONS"][check_task(task)]


def task_id(task: str) -> int:
    """LeRobot's index of the task among the 50 (the published dataset's ``task_id`` column)."""
    return int(_lerobot_metaworld_config()["TASK_NAME_TO_ID"][check_task(task)])


def require_metaworld() -> None:
    """RuntimeError with the install command when Meta-World, MuJoCo or gymnasium's renderer cannot work.

    Checked from package metadata, without importing them, so a command refuses in a fraction of a second.
    """
    for package in ("metaworld", "mujoco", "packaging"):
        if importlib.util.find_spec(package) is None:
            raise RuntimeError(f"{package} is not installed; {INSTALL_HINT}")
    mujoco_version = importlib.metadata.version("mujoco")
    # MuJoCo 4 changed the equality-constraint arrays Meta-World 3.0.0 writes at reset (reset_mocap_welds).
    if int(mujoco_version.split(".")[0]) >= 4:
        raise RuntimeError(f"mujoco {mujoco_version} breaks Meta-World 3.0.0; {INSTALL_HINT} (mujoco==3.3.7)")


def expert_policy(task: str) -> Any:
    """A fresh instance of Meta-World's scripted expert for ``task`` (the class LeRobot maps it to).

    The expert reads Meta-World's full 39-dim observation and returns a (4,) action in [-1, 1].
    """
    import metaworld.policies

    class_name = _lerobot_metaworld_config()["TASK_POLICY_MAPPING"][check_task(task)]
    return getattr(metaworld.policies, class_name)()
