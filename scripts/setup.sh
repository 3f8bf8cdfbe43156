#!/usr/bin/env bash
# Create (or reuse) .venv with Python 3.10 and install toffe-deploy with everything it needs.
# Lava 0.10 / lava-dl 0.6 require Python 3.10 exactly (see README, "Set-up").
# Re-running is cheap: the install is skipped while pyproject.toml is unchanged.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
EXTRAS=${EXTRAS:-lava,test,video}

find_python310() {
    local cand
    for cand in "${PYTHON310:-}" python3.10; do
        [ -n "$cand" ] || continue
        if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys; assert sys.version_info[:2] == (3, 10)' 2>/dev/null; then
            command -v "$cand"; return 0
        fi
    done
    local root
    root=$(pyenv root 2>/dev/null || echo "$HOME/.pyenv")
    for cand in "$root"/versions/3.10*/bin/python3.10 /usr/bin/python3.10 /usr/local/bin/python3.10; do
        if [ -x "$cand" ] && "$cand" -c 'import sys; assert sys.version_info[:2] == (3, 10)' 2>/dev/null; then
            echo "$cand"; return 0
        fi
    done
    return 1
}

if [ ! -x "$VENV/bin/python" ]; then
    if [ -n "${PYTHON310:-}" ] && ! "$PYTHON310" -c 'import sys; assert sys.version_info[:2] == (3, 10)' 2>/dev/null; then
        ver=$("$PYTHON310" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null || echo "not a Python")
        echo "toffe-deploy set-up: PYTHON310=$PYTHON310 is $ver, not Python 3.10 (Lava 0.10 needs exactly 3.10)." >&2
        exit 2
    fi
    if ! PY=$(find_python310); then
        echo "toffe-deploy set-up: Python 3.10 not found (Lava 0.10 needs exactly 3.10)." >&2
        echo "  Install it (e.g. 'pyenv install 3.10' or your distribution's python3.10) or set PYTHON310=/path/to/python3.10." >&2
        exit 2
    fi
    echo "toffe-deploy set-up: creating $VENV with $PY"
    "$PY" -m venv "$VENV"
fi

stamp="$VENV/.toffe-installed"
want="$(sha256sum pyproject.toml | cut -c1-16) $EXTRAS"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    echo "toffe-deploy set-up: installing toffe-deploy[$EXTRAS] into $VENV (first time: a few minutes, ~6 GB with torch)"
    # --no-cache-dir: the wheels (torch and its CUDA libraries, ~3.5 GB) are not kept a second
    # time in ~/.cache/pip; a CI runner with a small disk ran out of space with the cache on.
    "$VENV/bin/python" -m pip install -q --no-cache-dir --upgrade pip
    "$VENV/bin/python" -m pip install -q --no-cache-dir -e ".[$EXTRAS]"
    echo "$want" > "$stamp"
fi
