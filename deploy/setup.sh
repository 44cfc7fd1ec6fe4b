# Sourced by deploy/up.sh and tests/run.sh: make .venv with icefloe installed (editable), once.
# Usage: ensure_venv EXTRA   ("viz", "robot", "dev" or "planner"); installs again when pyproject.toml or
# the lock changes.
# Every version comes from the lock (deploy/requirements/<extra>.txt, exported from uv.lock by
# tools/lock.py; docs/DEVELOPING.md, "The lock"), with pip checking every file's hash: pip and
# setuptools first (build.txt), then the extra's packages, then icefloe itself with no dependencies.
# "planner": only what plans and runs a robot install (icefloe/deploy.py: icefloe and msgspec, no
# other dependency), so that a robot's install downloads the robot's dependencies once, into
# /opt/icefloe/venv, not twice.
# ICEFLOE_UNLOCKED=1: the newest release of everything within pyproject.toml's ranges instead
# (tests/run.sh --newest); so also on a machine the lock does not cover (not Linux on x86_64 or aarch64).
ensure_venv() {
    local extras="$1" py="${PYTHON:-python3}" lock=deploy/requirements
    if ! "$py" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
        echo "icefloe needs Python >= 3.11 (found: $("$py" --version 2>&1)); set PYTHON=/path/to/python3.11" >&2
        exit 1
    fi
    local locked=1
    if [ "${ICEFLOE_UNLOCKED:-0}" = 1 ]; then
        locked=0
    elif [ "$(uname -s)" != Linux ] || ! [[ "$(uname -m)" =~ ^(x86_64|aarch64)$ ]]; then
        echo "== the lock covers Linux on x86_64 and aarch64, not $(uname -s) $(uname -m):" \
             "installing the newest versions within pyproject.toml's ranges (untested)" >&2
        locked=0
    fi
    if [ ! -x .venv/bin/python ]; then
        echo "== creating .venv with $("$py" --version)"
        "$py" -m venv .venv
    fi
    local sum stamp
    sum="$(cat pyproject.toml "$lock/build.txt" "$lock/$extras.txt" 2>/dev/null | cksum | cut -d' ' -f1)"
    [ "$locked" = 1 ] || sum="unlocked-$(cksum < pyproject.toml | cut -d' ' -f1)"
    stamp=".venv/.icefloe-$extras-$sum"
    # the dev extra holds the viz extra: a developer's .venv runs up.sh as it is (the dev stamp's sum is
    # of dev.txt: without it, the box's `ensure_venv viz`, beside the suite in tests/run.sh, would
    # install icefloe again into the .venv the suite runs from)
    local dev_sum="$sum"
    if [ "$locked" = 1 ]; then
        dev_sum="$(cat pyproject.toml "$lock/build.txt" "$lock/dev.txt" 2>/dev/null | cksum | cut -d' ' -f1)"
    fi
    if [ "$extras" = viz ] && [ -e ".venv/.icefloe-dev-$dev_sum" ]; then
        return 0
    fi
    if [ "$extras" = planner ] && compgen -G ".venv/.icefloe-*" >/dev/null; then
        return 0  # any install of icefloe plans a robot install too
    fi
    [ -e "$stamp" ] && [ "${ICEFLOE_UNLOCKED:-0}" != 1 ] && return 0   # the newest: asked again each run
    local pip=(.venv/bin/python -m pip install --quiet)
    if [ "$locked" = 1 ]; then
        echo "== installing icefloe[$extras] into .venv, as locked ($lock/$extras.txt; first run takes a few minutes)"
        "${pip[@]}" --require-hashes -r "$lock/build.txt"
        "${pip[@]}" --require-hashes -r "$lock/$extras.txt"
        "${pip[@]}" --no-deps --no-build-isolation -e .
    else
        echo "== installing icefloe[$extras] into .venv: the newest versions within pyproject.toml's ranges"
        "${pip[@]}" --upgrade pip setuptools
        if [ "$extras" = planner ]; then
            "${pip[@]}" --upgrade "msgspec>=0.19" && "${pip[@]}" --no-deps -e .   # (as in pyproject.toml)
        else
            "${pip[@]}" --upgrade --upgrade-strategy eager -e ".[$extras]"
        fi
    fi
    rm -f .venv/.icefloe-"$extras"-*
    touch "$stamp"
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
