# Defines find_python312: prints the path of a working Python 3.12 (python3.12 on PATH, then pyenv's and the
# usual install locations; a pyenv shim without a 3.12 selected does not count). Sourced by setup_venv.sh and
# test_lerobot_main.sh.
find_python312() {
    local candidates=(python3.12)
    if command -v pyenv >/dev/null 2>&1; then
        candidates+=("$(pyenv root)"/versions/3.12*/bin/python3.12)
    fi
    candidates+=("$HOME"/.pyenv/versions/3.12*/bin/python3.12 /usr/local/bin/python3.12 /usr/bin/python3.12)
    for candidate in "${candidates[@]}"; do
        if "$candidate" -c 'import sys; assert sys.version_info[:2] == (3, 12)' >/dev/null 2>&1; then
            command -v "$candidate" 2>/dev/null || echo "$candidate"
            return 0
        fi
    done
    echo "no Python 3.12 found (tried python3.12 and pyenv versions); install Python 3.12" >&2
    return 1
}
