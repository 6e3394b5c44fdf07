#!/usr/bin/env bash
# Run the plugin's LeRobot contract tests against a LeRobot built from source (LeRobot's main branch before it
# is released), in a separate virtual environment: the project's .venv keeps the released LeRobot.
#
#   bash scripts/test_lerobot_main.sh <lerobot-source> [pytest args...]
#
# <lerobot-source> is one of
#   - a LeRobot source tree (a directory with pyproject.toml, e.g. a git checkout of main);
#   - an archive of one: .tar.gz / .tgz / .tar / .zip (e.g. `git archive --format=tar.gz --prefix=lerobot/ main`
#     run in a LeRobot clone; a `git archive` tarball also records the commit it was made from);
#   - a pip requirement URL, when the network reaches GitHub: git+https://github.com/huggingface/lerobot.git@main
#
# What it does: creates (or reuses) the venv, installs LeRobot from the source with the `dataset` and
# `training` extras plus this project editable with its `dev` extra, prints the LeRobot version and commit
# under test, and runs the contract tests (docs/lerobot_versions.md lists them): config registration and CLI
# parsing, make_policy, the processors, save/load, select_action and its queue, the compatibility shims, env
# registration, a tiny lerobot-train run with resume, and lerobot-eval end to end. Extra arguments go to
# pytest (e.g. -x, -k queue). The exit status is pytest's.
#
# Environment:
#   LEROBOT_TEST_VENV   the virtual environment to use (default: .venv-lerobot-main in the repository)
#   LEROBOT_TEST_TESTS  the test selection, space-separated (default: the contract tests below)
set -euo pipefail
unset PYTHONPATH  # the venv's own packages only
REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [ $# -lt 1 ]; then
    sed -n '2,21p' "$0" | sed 's/^# \{0,1\}//'
    exit 2
fi
SOURCE="$1"
shift
VENV="${LEROBOT_TEST_VENV:-$REPO_ROOT/.venv-lerobot-main}"
DEFAULT_TESTS=(
    tests/policies/test_lerobot_compat.py
    tests/policies/test_config.py
    tests/policies/test_policy.py
    tests/policies/test_processor.py
    tests/policies/test_checkpoint_loading.py
    tests/policies/test_lerobot_integration.py
    tests/test_lerobot_cli.py
    tests/envs/test_configs.py
    tests/envs/test_lerobot_eval.py
)
read -r -a TESTS <<< "${LEROBOT_TEST_TESTS:-${DEFAULT_TESTS[*]}}"

# 1. The requirement that installs LeRobot, and the commit it was made from when that can be known.
COMMIT="unknown"
case "$SOURCE" in
    git+* | http://* | https://*)
        REQUIREMENT="lerobot[dataset,training] @ $SOURCE"
        COMMIT="$SOURCE"
        ;;
    *)
        SOURCE="$(realpath "$SOURCE")"
        if [ -d "$SOURCE" ]; then
            SRC_DIR="$SOURCE"
            COMMIT="$(git -C "$SRC_DIR" rev-parse HEAD 2>/dev/null || echo "unknown (not a git checkout)")"
        elif [ -f "$SOURCE" ]; then
            # Unpacked afresh into the venv, so an archive of another commit never mixes with an older one.
            SRC_DIR="$VENV/lerobot-src"
            mkdir -p "$VENV"
            rm -rf "$SRC_DIR" && mkdir -p "$SRC_DIR"
            case "$SOURCE" in
                *.tar.gz | *.tgz)
                    tar -xzf "$SOURCE" -C "$SRC_DIR"
                    COMMIT="$(gzip -dc "$SOURCE" | git get-tar-commit-id 2>/dev/null || true)" ;;
                *.tar)
                    tar -xf "$SOURCE" -C "$SRC_DIR"
                    COMMIT="$(git get-tar-commit-id < "$SOURCE" 2>/dev/null || true)" ;;
                *.zip)
                    python3 -m zipfile -e "$SOURCE" "$SRC_DIR" ;;
                *)
                    echo "test_lerobot_main.sh: $SOURCE is not a .tar.gz/.tgz/.tar/.zip archive" >&2
                    exit 2 ;;
            esac
            COMMIT="${COMMIT:-unknown (the archive records no commit)}"
            # The archive's top folder (git archive --prefix) or the archive root itself.
            TOP="$(find "$SRC_DIR" -maxdepth 2 -name pyproject.toml -printf '%h\n' | sort | head -n 1)"
            SRC_DIR="${TOP:-$SRC_DIR}"
        else
            echo "test_lerobot_main.sh: $SOURCE is neither a directory, an archive nor a URL" >&2
            exit 2
        fi
        if ! grep -q '^name = "lerobot"' "$SRC_DIR/pyproject.toml" 2>/dev/null; then
            echo "test_lerobot_main.sh: $SRC_DIR has no LeRobot pyproject.toml" >&2
            exit 2
        fi
        REQUIREMENT="lerobot[dataset,training] @ file://$SRC_DIR"
        ;;
esac

# 2. The separate venv (Python 3.12, as LeRobot requires) with uv, which reuses its download cache (torch is not fetched again).
if [ ! -x "$VENV/bin/python" ]; then
    source "$REPO_ROOT/scripts/find_python312.sh"
    PYTHON312="$(find_python312)"
    echo "Creating $VENV with $PYTHON312"
    "$PYTHON312" -m venv "$VENV"
fi
if [ ! -x "$VENV/bin/uv" ]; then
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check "uv>=0.5,<1"
fi

# 3. LeRobot from the source, the plugin editable. Run from the repository so uv reads its [tool.uv] settings.
# --no-sources: LeRobot's own [tool.uv.sources] sends torch to a CUDA wheel index; install what its published
# metadata asks for, from PyPI, as `pip install lerobot` would.
echo "Installing $REQUIREMENT and lerobot_policy_subgoalvla[dev] into $VENV"
(cd "$REPO_ROOT" && VIRTUAL_ENV="$VENV" "$VENV/bin/uv" pip install --quiet --python "$VENV/bin/python" \
    --no-sources --reinstall-package lerobot "$REQUIREMENT" -e "$REPO_ROOT[dev]")

# 4. Say what is under test, and make sure it is the LeRobot just installed and this checkout of the plugin.
"$VENV/bin/python" - "$VENV" "$REPO_ROOT" <<'EOF'
import importlib.metadata as metadata
import sys
from pathlib import Path

import lerobot
import lerobot_subgoalvla

venv, repo = (Path(p).resolve() for p in sys.argv[1:])
lerobot_dir = Path(lerobot.__file__).resolve()
plugin_dir = Path(lerobot_subgoalvla.__file__).resolve()
print(f"LeRobot {metadata.version('lerobot')} from {lerobot_dir.parent}")
print(f"lerobot_policy_subgoalvla {metadata.version('lerobot_policy_subgoalvla')} from {plugin_dir.parent}")
if venv not in lerobot_dir.parents:
    sys.exit(f"LeRobot is imported from {lerobot_dir}, not from {venv}")
if repo not in plugin_dir.parents:
    sys.exit(f"the plugin is imported from {plugin_dir}, not from {repo}")
EOF
echo "LeRobot commit: $COMMIT"

# 5. The contract tests, with the venv's console scripts (lerobot-train, lerobot-eval) first on PATH.
export PATH="$VENV/bin:$PATH" VIRTUAL_ENV="$VENV"
export HF_HUB_OFFLINE=1 HF_DATASETS_OFFLINE=1 TRANSFORMERS_OFFLINE=1 MPLBACKEND=Agg
cd "$REPO_ROOT"
status=0
# The default suite of those files, plus their slow tests marked lerobot_contract (lerobot-eval of the checkpoint
# the tiny lerobot-train run saved).
"$VENV/bin/python" -m pytest -p no:cacheprovider -m "not slow or lerobot_contract" "${TESTS[@]}" "$@" || status=$?
echo "test_lerobot_main.sh: LeRobot $("$VENV/bin/python" -c 'import importlib.metadata as m; print(m.version("lerobot"))') (commit $COMMIT): pytest exit status $status"
exit "$status"
