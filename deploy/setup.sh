# Sourced by deploy/up.sh and tests/run.sh: make .venv with icefloe installed (editable), once.
# Usage: ensure_venv EXTRAS   (e.g. "viz" or "dev"); reinstalls when pyproject.toml changes.
ensure_venv() {
    local extras="$1" py="${PYTHON:-python3}"
    if ! "$py" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
        echo "icefloe needs Python >= 3.11 (found: $("$py" --version 2>&1)); set PYTHON=/path/to/python3.11" >&2
        exit 1
    fi
    if [ ! -x .venv/bin/python ]; then
        echo "== creating .venv with $("$py" --version)"
        "$py" -m venv .venv
    fi
    local stamp=".venv/.icefloe-$extras-$(cksum < pyproject.toml | cut -d' ' -f1)"
    if [ ! -e "$stamp" ]; then
        echo "== installing icefloe[$extras] into .venv (first run takes a few minutes)"
        .venv/bin/python -m pip install --quiet --upgrade pip
        .venv/bin/python -m pip install --quiet -e ".[$extras]"
        rm -f .venv/.icefloe-"$extras"-*
        touch "$stamp"
    fi
}
