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
echo "== pytest"
# Two workers, a test file each at a time (a file's tests share their robot): most tests wait on real
# service processes (2026-11-26, 2 cores: 892 tests in 14 min 10 s, the box test opt-in: docs/box.md;
# with six CPU-bound processes beside it, 16-19 min: docs/DEVELOPING.md). ICEFLOE_TEST_WORKERS=0: one process.
exec .venv/bin/pytest -n "${ICEFLOE_TEST_WORKERS:-2}" --dist loadfile "$@"
