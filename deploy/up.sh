#!/usr/bin/env bash
# Set up and run an icefloe robot.
#
#   ./deploy/up.sh                 the simulated robot, every service, in the foreground (Ctrl-C stops it)
#   ./deploy/up.sh penguin1        the robot config deploy/robots/penguin1.toml
#   ./deploy/up.sh --no-viz        without opening the Rerun viewer
#
# Any argument is passed to `icefloe up` (see `.venv/bin/icefloe up --help`).
set -euo pipefail
cd "$(dirname "$0")/.."
. deploy/setup.sh
ensure_venv viz
exec .venv/bin/icefloe up "$@"
