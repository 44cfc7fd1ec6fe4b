#!/usr/bin/env bash
# Set up (first run) and run the whole test suite: ./tests/run.sh [pytest arguments]
#   ./tests/run.sh --newest [pytest arguments]   the same suite against the newest release of every
#       dependency within pyproject.toml's ranges, in a copy of this checkout: what the next refresh of
#       the lock (tools/lock.py --upgrade) would break. It changes neither the lock nor .venv.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${1:-}" = --newest ]; then
    shift
    copy="${ICEFLOE_NEWEST_DIR:-/var/tmp/icefloe-newest-$(id -u)}"
    echo "== the suite against the newest versions, in a copy of this checkout: $copy (the lock is not changed)"
    mkdir -p "$copy"
    find "$copy" -mindepth 1 -maxdepth 1 ! -name .venv -exec rm -rf {} +   # its venv is kept: pip's cache
    tar --exclude=./.venv --exclude='__pycache__' --exclude=./.pytest_cache -cf - . | tar -xf - -C "$copy"
    status=0
    (cd "$copy" && ICEFLOE_UNLOCKED=1 ICEFLOE_BOX=0 ./tests/run.sh "$@") || status=$?
    echo "== the newest versions against the lock (what tools/lock.py --upgrade would change):"
    "$copy/.venv/bin/python" -m icefloe.lock || true
    [ "$status" = 0 ] && echo "== the newest versions pass the suite: refresh the lock (docs/DEVELOPING.md)" \
        || echo "== the newest versions fail the suite (exit $status): see above before refreshing the lock"
    exit "$status"
fi
. deploy/setup.sh
ensure_venv dev
if [ "${ICEFLOE_UNLOCKED:-0}" = 1 ]; then
    echo "== the newest versions within pyproject.toml's ranges, against the lock:"
    .venv/bin/python -m icefloe.lock || true
fi
ensure_apt Xvfb xvfb mesa-vulkan-drivers   # a display for the Rerun viewer tests and the screenshot
ensure_apt chromium chromium   # a real browser for the robot's page (tests/test_webapi_page.py, Playwright drives it)
# MessagePack for C and C++: the message code of examples/c and examples/cpp (tests/test_other_languages.py)
ensure_apt /usr/include/msgpack.hpp libmsgpack-dev libmsgpack-cxx-dev
# the robot in a box (tests/test_box.py, docs/box.md): Debian's root maker and systemd's container tool
ensure_apt debootstrap debootstrap
ensure_apt systemd-nspawn systemd-container
ensure_apt cyclictest rt-tests   # the machine's own latency beside the box's CPU hogs (test_box.py)
echo "== ruff"
.venv/bin/ruff check .
# The robot in a box (tests/test_box.py, docs/box.md) runs beside the rest of the suite, from the
# start: it waits on a booted Debian most of its time, and the suite's tests never use the robot's
# ports 7447 and 8080 that the box takes (they start their routers on free ports). As root only;
# its cached root and wheelhouse are made first if missing (once per machine; minutes).
box=1
for arg in "$@"; do [[ "$arg" == -* ]] || box=0; done   # a chosen test, or -k's words: no box
[ "${ICEFLOE_BOX:-1}" = 0 ] && box=0
box_log=/var/tmp/icefloe-box-test.log
if [ "$box" = 1 ] && [ "$(id -u)" = 0 ]; then
    echo "== the robot in a box, beside the suite (log: $box_log; ICEFLOE_BOX=0 leaves it out)"
    (
        set +e
        start=$SECONDS code=0
        if nice ./deploy/box.sh build; then
            echo "box: root and wheelhouse ready in $((SECONDS - start)) s"
            # its own temporary folder: two pytest runs at once must not prune each other's
            ICEFLOE_BOX=1 .venv/bin/pytest -p no:randomly -p no:cacheprovider --basetemp /var/tmp/icefloe-box-pytest \
                --durations=0 -rf tests/test_box.py "$@" || code=$?
        else
            echo "box: building the root or the wheelhouse failed"; code=1
        fi
        echo "box: $((SECONDS - start)) s in all"
        exit "$code"
    ) > "$box_log" 2>&1 &
    boxing=$!
fi
echo "== pytest"
# Two workers, a test file each at a time (a file's tests share their robot): most tests wait on real
# service processes (2026-11-26, 2 cores, fresh clone: 915 passed in 15 min 25 s with the box beside
# them, 16 min 28 s in all: docs/box.md; with six CPU-bound processes beside it, 16-19 min:
# docs/DEVELOPING.md). ICEFLOE_TEST_WORKERS=0: one process. The 30 slowest are listed: where CI's
# 25 minutes go.
status=0
ICEFLOE_BOX="$( [ "$box" = 1 ] && echo 0 || echo "${ICEFLOE_BOX:-0}")" \
    .venv/bin/pytest -n "${ICEFLOE_TEST_WORKERS:-2}" --dist loadfile --durations=30 "$@" || status=$?
if [ -n "${boxing:-}" ]; then
    echo "== the robot in a box (tests/test_box.py)"
    wait "$boxing" || status=1
    cat "$box_log"
elif [ "$box" = 1 ]; then
    echo "== the robot in a box: not as root, left out (docs/box.md)"
fi
exit "$status"
