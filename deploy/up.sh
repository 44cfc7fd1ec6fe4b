#!/usr/bin/env bash
# Set up and run an icefloe robot.
#
#   ./deploy/up.sh                     laptop/CI: the simulated robot, every service, in the foreground
#   ./deploy/up.sh penguin1            a robot config: deploy/robots/penguin1.toml (or a path)
#   ./deploy/up.sh --no-viz            without opening the Rerun viewer
#   ./deploy/up.sh penguin1 --dry-run  print every step of a robot install, change nothing
#   ./deploy/up.sh penguin1 --install  install the robot on a machine that is not a Raspberry Pi
#       --no-boot-config               ... without the Pi's boot config (/boot/firmware)
#       --source=SRC                   ... icefloe from SRC (a wheel, a requirement), not this checkout
#       --wheelhouse=DIR               ... every package from DIR (no download), refused unless it matches the lock
#
# On a Raspberry Pi whose config has [board] backend = "hardware", it installs the robot instead:
# /opt/icefloe/venv, system user, device permissions, boot config, credentials, one systemd unit
# per service (see icefloe/deploy.py and docs/deploy.md); ./deploy/down.sh undoes it.
# Other arguments go to `icefloe up` (see `.venv/bin/icefloe up --help`).
set -euo pipefail
cd "$(dirname "$0")/.."
. deploy/setup.sh

config="" mode=run deploy_args=()
for arg in "$@"; do
    case "$arg" in
        --dry-run) mode=dry ;;
        --install) mode=install ;;
        --no-boot-config|--source=*|--wheelhouse=*) deploy_args+=("$arg") ;;
        -*) ;;
        *) [ -z "$config" ] && config="$arg" ;;
    esac
done

is_pi() { grep -qs "Raspberry Pi" /proc/device-tree/model; }

backend() { .venv/bin/python -c 'import sys; from icefloe import config; print(config.load(sys.argv[1]).board.backend)' "$1" 2>/dev/null; }  # a bad config: `icefloe up` says why

if [ "$mode" = dry ] && [ -x .venv/bin/icefloe ]; then :   # a dry run plans with what is installed
elif is_pi || [ "$mode" != run ]; then ensure_venv planner   # the robot's own venv is /opt/icefloe/venv
else ensure_venv viz
fi
if [ "$mode" = run ] && is_pi; then
    if [ -n "$config" ] && [ "$(backend "$config")" = hardware ]; then mode=install
    else ensure_venv robot   # a Pi running a simulated robot in the foreground
    fi
fi

case "$mode" in
    dry) exec .venv/bin/python -m icefloe.deploy install "${config:-sim}" --dry-run ${deploy_args[@]+"${deploy_args[@]}"} ;;
    install)
        host=$(hostname -I 2>/dev/null | cut -d' ' -f1 || true)
        sudo=(sudo); [ "$(id -u)" = 0 ] && sudo=()
        exec ${sudo[@]+"${sudo[@]}"} .venv/bin/python -m icefloe.deploy install "${config:-sim}" --host "$host" \
            ${deploy_args[@]+"${deploy_args[@]}"} ;;
    run) exec .venv/bin/icefloe up "$@" ;;
esac
