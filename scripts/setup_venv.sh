# Create or reuse the project's Python 3.12 virtual environment in .venv and install the project into it.
# Sourced by scripts/test.sh and scripts/demo.sh; safe to run again (it reinstalls only when pyproject.toml changed).
set -euo pipefail
REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$REPO_ROOT/.venv"

source "$REPO_ROOT/scripts/find_python312.sh"

if [ ! -x "$VENV/bin/python" ]; then
    PYTHON312="$(find_python312)"
    echo "Creating $VENV with $PYTHON312"
    "$PYTHON312" -m venv "$VENV"
fi
if [ ! -x "$VENV/bin/uv" ]; then
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check "uv>=0.5,<1"
fi

STAMP="$VENV/.installed-pyproject.sha256"
WANT="$(sha256sum "$REPO_ROOT/pyproject.toml" | cut -d' ' -f1)"
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$WANT" ]; then
    echo "Installing lerobot_policy_subgoalvla and its dependencies into $VENV (first time: several minutes)"
    VIRTUAL_ENV="$VENV" "$VENV/bin/uv" pip install --python "$VENV/bin/python" -e "$REPO_ROOT[dev,viz,metaworld]"
    echo "$WANT" > "$STAMP"
    # LeRobot's default video decoder needs FFmpeg's shared libraries (system packages, not pip's).
    if ! "$VENV/bin/python" -c "import torchcodec" >/dev/null 2>&1; then
        echo "Note: torchcodec cannot load FFmpeg's shared libraries; LeRobot will decode videos with PyAV (slower)." \
             "For torchcodec on Debian 12: apt-get install libavutil57 libavcodec59 libavformat59 libavdevice59" \
             "libavfilter8 libswscale6 libswresample4"
    fi
fi
# Compiled bytecode makes each of the many subprocesses (lerobot-train, workers) start seconds faster.
unset PYTHONDONTWRITEBYTECODE
export PATH="$VENV/bin:$PATH"
export VIRTUAL_ENV="$VENV"
