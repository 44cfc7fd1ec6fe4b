#!/usr/bin/env bash
# Set up (first run) and run the whole test suite: ./tests/run.sh [pytest arguments]
set -euo pipefail
cd "$(dirname "$0")/.."
. deploy/setup.sh
ensure_venv dev
ensure_apt Xvfb xvfb mesa-vulkan-drivers   # a display for the Rerun viewer tests and the screenshot
ensure_apt chromium chromium   # a real browser for the robot's page (tests/test_webapi_page.py, Playwright drives it)
# MessagePack for C and C++: the message code of examples/c and examples/cpp (tests/test_other_languages.py)
ensure_apt /usr/include/msgpack.hpp libmsgpack-dev libmsgpack-cxx-dev
# the robot in a box (tests/test_box.py, docs/box.md): Debian's root maker and systemd's container tool
ensure_apt debootstrap debootstrap
ensure_apt systemd-nspawn systemd-container
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
# docs/DEVELOPING.md). ICEFLOE_TEST_WORKERS=0: one process.
status=0
ICEFLOE_BOX="$( [ "$box" = 1 ] && echo 0 || echo "${ICEFLOE_BOX:-0}")" \
    .venv/bin/pytest -n "${ICEFLOE_TEST_WORKERS:-2}" --dist loadfile "$@" || status=$?
if [ -n "${boxing:-}" ]; then
    echo "== the robot in a box (tests/test_box.py)"
    wait "$boxing" || status=1
    cat "$box_log"
elif [ "$box" = 1 ]; then
    echo "== the robot in a box: not as root, left out (docs/box.md)"
fi
exit "$status"
