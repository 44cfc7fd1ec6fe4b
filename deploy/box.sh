#!/usr/bin/env bash
# The robot in a box: a fresh Debian bookworm, booted with systemd-nspawn, where the robot is
# installed as a TA installs it on a Raspberry Pi, with the simulated board outside (docs/box.md).
#
#   sudo ./deploy/box.sh              build the root once (cached), boot a fresh box, install penguin1 as pi
#   sudo ./deploy/box.sh exec --user pi -- icefloe status      a command in the box
#   sudo ./deploy/box.sh board pose   the simulator's truth (x y theta)
#   sudo ./deploy/box.sh down         power the box off and throw it away
#
# `./deploy/box.sh --help` lists every command. Needs root, debootstrap and systemd-container;
# `--arch arm64` (emulated: slow) also qemu-user-static and binfmt-support.
set -euo pipefail
cd "$(dirname "$0")/.."
. deploy/setup.sh
if [ "$(id -u)" != 0 ]; then
    echo "box: run as root (sudo ./deploy/box.sh): booting a box needs it" >&2
    exit 1
fi
ensure_apt debootstrap debootstrap
ensure_apt systemd-nspawn systemd-container
case " $* " in   # an arm64 box runs its programs under qemu's user emulation (binfmt_misc)
    *" --arch arm64 "*|*" --arch=arm64 "*) ensure_apt qemu-aarch64-static qemu-user-static binfmt-support ;;
esac
ensure_venv viz   # this machine's side: the board model, and the laptop's icefloe that drives the box
exec .venv/bin/python deploy/box/box.py "$@"
