#!/usr/bin/env bash
# The robot in a box: a fresh Debian bookworm, booted with systemd-nspawn, where the robot is
# installed as a TA installs it on a Raspberry Pi, with the simulated board outside (docs/box.md).
#
#   sudo ./deploy/box.sh              build the root once (cached), boot a fresh box, install penguin1 as pi
#   sudo ./deploy/box.sh exec --user pi -- icefloe status      a command in the box
#   sudo ./deploy/box.sh board pose   the simulator's truth (x y theta)
#   sudo ./deploy/box.sh down         power the box off and throw it away
#
# `./deploy/box.sh --help` lists every command, as any user, and installs nothing. Needs root,
# debootstrap and systemd-container; `--arch arm64` (emulated: slow) also qemu-user-static and
# binfmt-support. Run as root, it leaves no file of root's in the checkout: the .venv is made
# as the checkout's owner, and Python writes no bytecode here.
set -euo pipefail
cd "$(dirname "$0")/.."
for arg in "$@"; do   # help (asked before a "--" that starts a command for the box): box.py's, stdlib only
    case "$arg" in
        --) break ;;
        -h|--help) exec "${PYTHON:-python3}" -B deploy/box/box.py "$@" ;;
    esac
done
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
# This machine's side (the board model, and the laptop's icefloe that drives the box) runs from the
# checkout's .venv: made or updated as the checkout's owner, so root leaves nothing of its own here.
owner="$(stat -c %U .)"
if [ "$owner" = root ]; then
    ensure_venv viz
else
    runuser -u "$owner" -- env HOME="$(getent passwd "$owner" | cut -d: -f6)" \
        bash -c '. deploy/setup.sh && ensure_venv viz'
fi
export PYTHONDONTWRITEBYTECODE=1   # no __pycache__ of root's in the checkout
exec .venv/bin/python deploy/box/box.py "$@"
