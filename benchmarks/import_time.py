"""Start-up cost: wall time of each command's ``--help`` and of an env worker's first reset, in fresh
processes.

Each row runs ``--repeats`` fresh interpreters (``python -c``) one after the other and reports the median wall
time, and which heavy libraries the process ended up importing. The light commands (report, chains, demo
report, generator) must stay clear of torch and LeRobot; the converter and the trace renderer need them.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/import_time.py --repeats 5
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import textwrap
import time

COMMANDS = {
    "subgoalvla-calvin-report": "lerobot_subgoalvla.envs.calvin.evaluation.report",
    "subgoalvla-calvin-chains": "lerobot_subgoalvla.envs.calvin.evaluation.chains",
    "subgoalvla-demo-report": "lerobot_subgoalvla.demo_report",
    "subgoalvla-generate-calvin": "lerobot_subgoalvla.datasets_conversion.generate_calvin",
    "subgoalvla-convert-calvin": "lerobot_subgoalvla.datasets_conversion.convert_calvin",
    "subgoalvla-render-traces": "lerobot_subgoalvla.visualization.render_traces",
}
HEAVY = ("torch", "transformers", "lerobot", "matplotlib")
_REPORT = f"print(','.join(m for m in {HEAVY!r} if m in sys.modules) or '-')"


def help_script(module: str) -> str:
    return textwrap.dedent(
        f"""
        import contextlib, importlib, io, sys
        sys.argv = [{module!r}, "--help"]
        with contextlib.suppress(SystemExit), contextlib.redirect_stdout(io.StringIO()):
            importlib.import_module({module!r}).main()
        {_REPORT}
        """
    )


WORKER_SCRIPT = textwrap.dedent(
    f"""
    import sys
    from lerobot_subgoalvla.envs.calvin.vector import make_frozen_env
    make_frozen_env(task="open_drawer").reset(seed=0)
    {_REPORT}
    """
)


def measure(script: str, repeats: int) -> tuple[float, str]:
    seconds, imported = [], ""
    for _ in range(repeats):
        start = time.perf_counter()
        result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
        seconds.append(time.perf_counter() - start)
        imported = result.stdout.strip().splitlines()[-1]
    return statistics.median(seconds), imported


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="fresh processes per row (median reported)")
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} cores, median of {args.repeats} runs")
    print(f"| {'what':<46} | {'wall s':>6} | heavy modules imported |")
    print(f"| {'-' * 46} | {'-' * 6} | {'-' * 22} |")
    rows = [(f"{name} --help", help_script(module)) for name, module in COMMANDS.items()]
    rows.append(("env worker: build + first reset (open_drawer)", WORKER_SCRIPT))
    for label, script in rows:
        seconds, imported = measure(script, args.repeats)
        print(f"| {label:<46} | {seconds:6.2f} | {imported:<22} |")


if __name__ == "__main__":
    main()
