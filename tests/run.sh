#!/usr/bin/env bash
# Set up (first run) and run the whole test suite: ./tests/run.sh [pytest arguments]
set -euo pipefail
cd "$(dirname "$0")/.."
. deploy/setup.sh
ensure_venv dev
ensure_apt Xvfb xvfb mesa-vulkan-drivers   # a display for the Rerun viewer tests and the screenshot
echo "== ruff"
.venv/bin/ruff check .
echo "== pytest"
exec .venv/bin/pytest "$@"
