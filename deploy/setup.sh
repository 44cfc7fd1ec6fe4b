# Sourced by deploy/up.sh and tests/run.sh: make .venv with icefloe installed (editable), once.
# Usage: ensure_venv EXTRAS   (e.g. "viz" or "dev"); reinstalls when pyproject.toml changes.
# "planner": only what plans and runs a robot install (icefloe/deploy.py: icefloe and msgspec, no
# other dependency), so that a robot's install downloads the robot's dependencies once, into
# /opt/icefloe/venv, not twice.
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
    local sum stamp
    sum="$(cksum < pyproject.toml | cut -d' ' -f1)"
    stamp=".venv/.icefloe-$extras-$sum"
    if [ "$extras" = viz ] && [ -e ".venv/.icefloe-dev-$sum" ]; then
        return 0  # the dev extra holds the viz extra: a developer's .venv runs up.sh as it is
    fi
    if [ "$extras" = planner ] && compgen -G ".venv/.icefloe-*-$sum" >/dev/null; then
        return 0  # any install of icefloe plans a robot install too
    fi
    if [ "$extras" = planner ]; then
        echo "== installing icefloe's robot installer into .venv (icefloe and msgspec only)"
        .venv/bin/python -m pip install --quiet "msgspec>=0.19"   # (as in pyproject.toml)
        .venv/bin/python -m pip install --quiet --no-deps -e .
        touch "$stamp"
    elif [ ! -e "$stamp" ]; then
        echo "== installing icefloe[$extras] into .venv (first run takes a few minutes)"
        .venv/bin/python -m pip install --quiet --upgrade pip
        .venv/bin/python -m pip install --quiet -e ".[$extras]"
        rm -f .venv/.icefloe-"$extras"-*
        touch "$stamp"
    fi
}

# Usage: ensure_apt COMMAND PACKAGE...   install Debian packages when COMMAND is missing, if we are
# root on Debian (tests/run.sh: Xvfb and Mesa's software renderers for the viewer tests). Otherwise
# say so and go on: the tests that need them skip and say why.
ensure_apt() {
    local cmd="$1"; shift   # a command, or the path of a file the packages install
    if [[ "$cmd" == /* ]]; then [ -e "$cmd" ] && return 0; else command -v "$cmd" >/dev/null && return 0; fi
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        echo "== installing $* (apt-get)"
        { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@"; } >/dev/null \
            || echo "   could not install $*: the tests that need $cmd will skip"
    else
        echo "== $cmd is missing (apt-get install $*): the tests that need it will skip"
    fi
}
