#!/usr/bin/env bash
# The test command of the README: sets up .venv, lints, runs the default (fast, offline) test suite.
#   bash scripts/test.sh            # default suite (< 20 min on 2 CPU cores)
#   bash scripts/test.sh --slow     # only the slow tests (expert success rates, long training runs, ...)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup_venv.sh
export HF_HUB_OFFLINE=1 HF_DATASETS_OFFLINE=1 TRANSFORMERS_OFFLINE=1
export MPLBACKEND=Agg
ruff check .
ruff format --check .
if [ "${1:-}" = "--slow" ]; then
    shift
    exec python -m pytest -m slow "$@"
fi
exec python -m pytest "$@"
