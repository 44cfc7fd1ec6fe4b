#!/usr/bin/env bash
# Undo deploy/up.sh on a robot: remove exactly what its install added, as listed in
# /opt/icefloe/install.json (units, udev rules, tmpfiles entry, boot lines, the user icefloe,
# /opt/icefloe, the config files in /etc/icefloe). Apt packages stay installed; the robot's
# credentials file stays (root's, mode 0600) unless --purge: see docs/deploy.md.
#   ./deploy/down.sh CONFIG [--dry-run] [--purge]
set -euo pipefail
cd "$(dirname "$0")/.."
config="${1:?usage: deploy/down.sh CONFIG [--dry-run] [--purge]}"
shift
python=.venv/bin/python
[ -x "$python" ] || python=/opt/icefloe/venv/bin/python   # a checkout whose .venv is gone: the robot's own
for arg in "$@"; do
    if [ "$arg" = "--dry-run" ]; then exec "$python" -m icefloe.deploy remove "$config" "$@"; fi
done
sudo=(sudo); [ "$(id -u)" = 0 ] && sudo=()
exec ${sudo[@]+"${sudo[@]}"} "$python" -m icefloe.deploy remove "$config" "$@"
