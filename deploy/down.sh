#!/usr/bin/env bash
# Undo deploy/up.sh on a robot: stop and remove the systemd units and device rules.
# The credentials file and the boot config are left as they are.
#   ./deploy/down.sh CONFIG [--dry-run]
set -euo pipefail
cd "$(dirname "$0")/.."
config="${1:?usage: deploy/down.sh CONFIG [--dry-run]}"
shift
if [ "${1:-}" = "--dry-run" ]; then
    exec .venv/bin/python -m icefloe.deploy remove "$config" --dry-run
fi
exec sudo .venv/bin/python -m icefloe.deploy remove "$config"
