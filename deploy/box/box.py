"""The robot in a box: a fresh Debian bookworm booted with systemd-nspawn, installed as a TA would.

    deploy/box.sh [up]            build the root once (cached), boot a fresh copy, install penguin1 as pi
                                  (in a memory limit the size of a Raspberry Pi 3B's: --memory MIB)
    deploy/box.sh exec [--user pi] -- CMD...   run a command in the box
    deploy/box.sh board pose|unplug|plug|stopped|received   the board outside the box (pose: the
                                  simulator's truth; received: when the last stop reached it, and its zero duty)
    deploy/box.sh reboot | down               reboot the box | power it off and throw it away

The root (`build`) is made once with debootstrap from Debian's packages and kept in a cache outside
the checkout (``--cache``, default /var/cache/icefloe/box); every `up` boots a fresh copy (an
overlay over the cached root) that `down` throws away. The box shares the host's network: the
robot's router is then 127.0.0.1:7447 and its web API :8080, as a laptop in the lab reaches a robot.

The board is the simulator's PenguinPi model, run by this program (the box's supervisor) *outside*
the box, on a pseudo-terminal made in the box's own /dev/pts and linked as /dev/serial0, with the
group and mode the install's udev rule gives the Pi's UART (the box has no udev). World physics and
the simulator's truth stay outside, as the floor does for a real robot: `board pose` reads them.

What a Raspberry Pi has and the box lacks is said explicitly, in the install's own flags (docs/box.md):
``./deploy/up.sh penguin1 --install --no-boot-config --wheelhouse=/var/cache/icefloe-box/wheels``, the
wheelhouse being the lock's files for the box's machine, downloaded here once per lock (`wheelhouse`).
Box infrastructure, not the robot's: pi's passwordless sudo (the TA typing a password), a pip and an apt
cache bound from the host.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import json
import os
import shlex
import shutil
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import tty
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SUITE = "bookworm"
MIRROR = "http://deb.debian.org/debian"
PACKAGES = [
    # what a stock Raspberry Pi OS Lite (bookworm) has that an install touches; no compiler, no headers
    "systemd", "systemd-sysv", "dbus", "udev", "kmod", "sudo", "adduser", "passwd", "git", "python3",
    "python3-venv", "ca-certificates", "iproute2", "procps", "less", "nano", "locales", "tzdata",
]
SOURCES = f"""\
deb {MIRROR} {SUITE} main
deb {MIRROR} {SUITE}-updates main
deb http://deb.debian.org/debian-security {SUITE}-security main
"""
READY = ".icefloe-box-ready"
"""Marker file in a finished cached root (a root half made by an interrupted build has none)."""
BOX_PIP = "/var/cache/icefloe-box/pip"
BOX_WHEELS = "/var/cache/icefloe-box/wheels"
LOCKED = ("build", "planner", "viz", "robot")
"""The lock's exports whose files the box's wheelhouse holds: what the README's command (build, viz) and the
robot install (build, planner, robot) take from the lock (`wheelhouse`)."""
BOX_PYTHON = "3.11"
"""Bookworm's Python: the box's, and a Raspberry Pi OS robot's (the wheelhouse holds its wheels)."""
MACHINE = {"amd64": "x86_64", "arm64": "aarch64"}
"""Debian's name of an architecture -> the machine the lock's markers name (``platform_machine``)."""
BOX_APT = "/var/cache/apt/archives"
BOARD_CONFIG = "sim"
"""The simulated robot's config gives the board model (penguin1 extends it: the same geometry)."""
SERIAL = "/dev/serial0"
TIOCGPTN, TIOCSPTLCK = 0x80045430, 0x40045431
REBOOT_STATUS = 133
"""systemd-nspawn's exit status when the box's systemd asked for a reboot."""
PATH = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"
EMULATED = {"arm64": "aarch64"}
"""A box of this architecture runs its programs under qemu's user emulation (binfmt_misc: qemu-<name>)."""
SLOWER = {"arm64": 10.0}
"""How much longer the box's own waits (boot, reboot) are under emulation (docs/box.md: measured)."""


def say(msg: str) -> None:
    print(f"box: {msg}", flush=True)


class BoxError(Exception):
    """One line for the user: what went wrong and what to do."""


# ---------------------------------------------------------------------------------------- the root

def cached_root(cache: Path, arch: str) -> Path:
    return cache / f"{SUITE}-{arch}"


def emulated(arch: str) -> str:
    """qemu's name of ``arch`` if this machine runs its programs under emulation, else ''."""
    qemu = EMULATED.get(arch, "")
    return qemu if qemu and os.uname().machine != qemu else ""


def emulation(arch: str, setuid: bool = False) -> None:
    """Make sure this machine runs ``arch``'s programs if the box needs qemu for them: binfmt_misc
    mounted, qemu's entry enabled with the F flag (the interpreter opened when registered, so it
    runs in a chroot and in the box, where /usr/libexec/qemu-binfmt does not exist). ``setuid``:
    a booted box runs sudo, which needs the C flag too (docs/box.md: Debian registers qemu without it)."""
    qemu = emulated(arch)
    if not qemu:
        return
    misc = Path("/proc/sys/fs/binfmt_misc")
    if not (misc / "status").exists():
        subprocess.run(["mount", "-t", "binfmt_misc", "binfmt_misc", str(misc)], capture_output=True)
    entry = misc / f"qemu-{qemu}"
    if not entry.exists() and shutil.which("update-binfmts"):
        subprocess.run(["update-binfmts", "--enable", f"qemu-{qemu}"], capture_output=True)
    try:
        lines = entry.read_text().splitlines()
    except OSError:
        raise BoxError(f"this machine cannot run {arch} programs: no binfmt_misc entry {entry} "
                       f"(apt-get install qemu-user-static binfmt-support; update-binfmts --enable qemu-{qemu})"
                       ) from None
    flags = next((line.split(":", 1)[1] for line in lines if line.startswith("flags:")), "")
    if lines[:1] != ["enabled"] or "F" not in flags:
        raise BoxError(f"{entry} is not enabled with the F flag ({' '.join(lines[:1])}, flags{flags or ' none'}): "
                       f"a box cannot run {arch} programs; qemu-user-static's own entry has it "
                       f"(update-binfmts --enable qemu-{qemu})")
    if setuid and "C" not in flags:
        raise BoxError(f"{entry} has no C flag (flags{flags}): in an {arch} box sudo, a setuid program, would run "
                       f"without root's rights and the install as pi fails; docs/box.md says how to register "
                       f"qemu-{qemu} with it for the box's run, and why Debian does not")


def slower(state: State) -> float:
    return SLOWER.get(state.read().get("arch", ""), 1.0)


def wheels_dir(cache: Path, arch: str) -> Path:
    """The wheelhouse of a box of ``arch`` (each its own: an arm64 box gets no amd64 wheels)."""
    return cache / ("wheels" if arch == "amd64" else f"wheels-{arch}")


def build(cache: Path, arch: str, rebuild: bool = False) -> Path:
    """The cached root for ``arch``, made with debootstrap if it is missing (a few minutes, once)."""
    emulation(arch)
    root = cached_root(cache, arch)
    if (root / READY).exists() and not rebuild:
        return root
    for tool in ("debootstrap", "systemd-nspawn"):
        if not shutil.which(tool):
            raise BoxError(f"{tool} is missing: apt-get install debootstrap systemd-container")
    partial = root.with_name(root.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    partial.parent.mkdir(parents=True, exist_ok=True)
    say(f"making the {SUITE} {arch} root with debootstrap in {root} (once; a few minutes)")
    start = time.monotonic()
    cmd = ["debootstrap", "--variant=minbase", f"--arch={arch}", f"--include={','.join(PACKAGES)}",
           SUITE, str(partial), MIRROR]
    log = cache / f"debootstrap-{arch}.log"
    with log.open("w") as out:
        if subprocess.run(cmd, stdout=out, stderr=subprocess.STDOUT).returncode != 0:
            raise BoxError(f"debootstrap failed: see {log}")
    (partial / "etc/apt/sources.list").write_text(SOURCES)
    (partial / "etc/hostname").write_text("raspberrypi\n")
    # Debian's root has the CA list of its ca-certificates; this machine's may hold a proxy's CA
    # that pip needs to reach PyPI from here.
    host_ca = Path("/etc/ssl/certs/ca-certificates.crt")
    if host_ca.exists():
        shutil.copy(host_ca, partial / "etc/ssl/certs/ca-certificates.crt")
    with contextlib.suppress(FileNotFoundError):
        (partial / "etc/machine-id").unlink()   # each box gets its own at first boot
    (partial / "etc/machine-id").write_text("")
    subprocess.run(["chroot", str(partial), "apt-get", "clean"], check=False)
    (partial / READY).write_text(time.strftime("%Y-%m-%dT%H:%M:%SZ\n", time.gmtime()))
    shutil.rmtree(root, ignore_errors=True)
    partial.rename(root)
    size = subprocess.run(["du", "-sh", str(root)], capture_output=True, text=True).stdout.split()[0]
    say(f"root ready in {time.monotonic() - start:.0f} s ({size})")
    return root


def locked_pins(repo: Path, rev: str, arch: str) -> tuple[dict, str]:
    """The lock's pins for a box of ``arch`` (`LOCKED`: what its installs take), read from ``rev`` of
    ``repo`` (the commit the box clones, not the working tree), and a digest of those exports."""
    import hashlib
    import tempfile

    from icefloe import lock

    digest = hashlib.sha256(f"{arch} {BOX_PYTHON}".encode())
    with tempfile.TemporaryDirectory(prefix="icefloe-box-lock-") as tmp:
        for name in LOCKED:
            path = f"deploy/requirements/{name}.txt"
            r = subprocess.run(["git", "-C", str(repo), "show", f"{rev}:{path}"], capture_output=True, text=True)
            if r.returncode != 0:
                raise BoxError(f"{repo} at {rev}: no {path} (the lock's export; tools/lock.py makes it): "
                               f"{r.stderr.strip()}")
            (Path(tmp) / f"{name}.txt").write_text(r.stdout)
            digest.update(r.stdout.encode())
        environment = lock.environment(MACHINE[arch], BOX_PYTHON)
        try:
            return lock.pins(LOCKED, environment=environment, directory=Path(tmp)), digest.hexdigest()[:16]
        except lock.LockError as exc:
            raise BoxError(f"{repo} at {rev}: {exc}") from None


def pip_target(arch: str) -> list[str]:
    """pip download's options for a box of ``arch``: bookworm's CPython 3.11 and glibc 2.36 (pip does not
    widen manylinux_2_36 to the older glibc tags itself), wheels only (the box has no compiler), whatever
    Python and machine this is."""
    machine = MACHINE[arch]
    return [*(f"--platform=manylinux_2_{m}_{machine}" for m in range(36, 16, -1)),
            f"--platform=manylinux2014_{machine}", f"--python-version={BOX_PYTHON}", "--implementation=cp",
            f"--abi=cp{BOX_PYTHON.replace('.', '')}", "--only-binary=:all:"]


def wheelhouse(repo: Path, folder: Path, arch: str = "amd64", rev: str = "HEAD") -> None:
    """The lock's files for a box of ``arch``, downloaded once per lock into ``folder`` (docs/box.md).

    Exactly the lock's: each pin of `LOCKED` with its hashes, ``pip download --no-deps
    --require-hashes`` (pip checks every file's sha256), then checked as the robot install checks a
    wheelhouse (`icefloe.lock.wheelhouse_problems`); a file of an older lock is removed. A wheelhouse
    that does not match is an error naming what is missing.
    """
    from icefloe import lock

    locked, digest = locked_pins(repo, rev, arch)
    stamp = folder / f".stamp-{digest}"
    if stamp.exists():
        return
    folder.mkdir(parents=True, exist_ok=True)
    say(f"downloading the lock's {len(locked)} packages for {arch} into {folder} (once per lock)")
    start = time.monotonic()
    pinned = folder / ".requirements.txt"
    pinned.write_text("".join(pin.requirement() + "\n" for _, pin in sorted(locked.items())))
    r = subprocess.run([sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--require-hashes",
                        "--dest", str(folder), *pip_target(arch), "-r", str(pinned)], capture_output=True, text=True)
    if r.returncode != 0:
        raise BoxError(f"pip could not download the lock's files into {folder}: "
                       + " ".join(r.stderr.strip().splitlines()[-3:]))
    allowed = set().union(*(pin.hashes for pin in locked.values()))
    for f in folder.iterdir():
        if f.is_file() and not f.name.startswith(".") and lock.sha256(f) not in allowed:
            f.unlink()  # another lock's file: the box takes the lock's only
    problems = lock.wheelhouse_problems(folder, locked)
    if problems:
        raise BoxError(f"the wheelhouse {folder} does not match the lock after pip's download: " + "; ".join(problems))
    for old in folder.glob(".stamp-*"):
        old.unlink()
    stamp.touch()
    say(f"wheelhouse ready in {time.monotonic() - start:.0f} s: {len(locked)} packages as locked")


# ---------------------------------------------------------------------------------------- state

class State:
    """The running box's folder: the overlay, its console log, the supervisor's socket."""

    def __init__(self, folder: Path) -> None:
        self.dir = folder
        self.upper, self.work, self.root = folder / "upper", folder / "work", folder / "root"
        self.sock = folder / "box.sock"
        self.console = folder / "console.log"
        self.info = folder / "box.json"

    def read(self) -> dict:
        try:
            return json.loads(self.info.read_text())
        except (FileNotFoundError, ValueError):
            return {}

    def write(self, **values: object) -> None:
        data = {**self.read(), **values}
        tmp = self.info.with_suffix(".tmp")
        tmp.write_text(json.dumps(data))
        tmp.replace(self.info)


def ask(state: State, command: str, timeout: float = 30.0) -> str:
    """One request to the box's supervisor (see `Supervisor.handle`)."""
    try:
        with socket.socket(socket.AF_UNIX) as s:
            s.settimeout(timeout)
            s.connect(str(state.sock))
            s.sendall(command.encode() + b"\n")
            reply = s.makefile().readline().strip()
    except OSError as exc:
        raise BoxError(f"no box is running in {state.dir} ({exc.strerror or exc}): deploy/box.sh up") from None
    if reply.startswith("error "):
        raise BoxError(reply[6:])
    return reply


# ---------------------------------------------------------------------------------------- the board

def box_pty(leader: int) -> tuple[int, int, str]:
    """A pseudo-terminal in the devpts of the box whose PID 1 is ``leader``: (master, slave, name
    inside the box), the slave with the group and mode the install's udev rule gives the Pi's UART."""
    pts = Path(f"/proc/{leader}/root/dev/pts")
    master = os.open(pts / "ptmx", os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    fcntl.ioctl(master, TIOCSPTLCK, struct.pack("i", 0))
    number = struct.unpack("i", fcntl.ioctl(master, TIOCGPTN, b"\0" * 4))[0]
    slave = os.open(pts / str(number), os.O_RDWR | os.O_NOCTTY)
    tty.setraw(slave)  # no echo until hwbridge's pyserial sets the line up (as PtyLink does)
    dialout = 20
    with contextlib.suppress(KeyError, OSError, ValueError):
        for line in Path(f"/proc/{leader}/root/etc/group").read_text().splitlines():
            if line.startswith("dialout:"):
                dialout = int(line.split(":")[2])
    os.chown(pts / str(number), 0, dialout)
    os.chmod(pts / str(number), 0o660)
    return master, slave, f"/dev/pts/{number}"


class Board:
    """The simulator (world + PenguinPi firmware model, icefloe's `Simulator`) with its serial line
    moved into the box: the model's `PtyLink` keeps running; only the terminal under it changes."""

    def __init__(self, state: State) -> None:
        from icefloe import config as config_mod
        from icefloe.services.sim.simulator import Simulator

        sys.setswitchinterval(0.0002)  # as the simulator service: the board answers within a cycle
        folder = state.dir / "board"
        folder.mkdir(mode=0o700, exist_ok=True)
        cfg = config_mod.load(BOARD_CONFIG)
        import msgspec

        cfg = msgspec.structs.replace(cfg, run_dir=str(folder), board=msgspec.structs.replace(
            cfg.board, serial_port=str(folder / "ttyPPI")))
        self.sim = Simulator(cfg)
        self.link = self.sim.board.link
        self.sim.start()
        self.leader = 0
        self.where = ""
        self.lock = threading.Lock()

    def _swap(self, master: int, slave: int) -> None:
        # dup2 onto the link's own descriptors: its reader polls and its writer writes the same
        # numbers, now the new terminal; the old one closes (hwbridge's end sees the line drop).
        os.dup2(master, self.link._master)
        os.dup2(slave, self.link._slave)
        os.close(master)
        os.close(slave)

    def plug(self, leader: int) -> str:
        with self.lock:
            master, slave, name = box_pty(leader)
            self._swap(master, slave)
            link = Path(f"/proc/{leader}/root{SERIAL}")
            tmp = link.with_name(".serial0.tmp")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            tmp.symlink_to(name)
            tmp.replace(link)
            self.leader, self.where = leader, name
            return name

    def unplug(self) -> None:
        with self.lock:
            with contextlib.suppress(FileNotFoundError):
                Path(f"/proc/{self.leader}/root{SERIAL}").unlink()
            master, slave = os.openpty()  # a terminal nobody reads: the board talks into the void
            os.set_blocking(master, False)
            self._swap(master, slave)
            self.where = ""

    def pose(self) -> str:
        x, y, theta = self.sim.world.pose
        return f"{x:.6f} {y:.6f} {theta:.6f}"

    def stopped(self) -> str:
        """Since when both wheels' duty has been zero, on this machine's ``time.monotonic()`` clock
        (a test outside the box times a stop with it), or ``moving``."""
        world = self.sim.world
        now, since = time.monotonic(), world.zero_duty_since
        if since < 0:
            return "moving"
        return f"{now - (world.time - since):.6f}"  # the simulator's clock runs at the real rate

    def received(self) -> str:
        """When the last stop reached the board (the datagram that zeroed both wheels' demand), on this
        machine's ``time.monotonic()`` clock, and when the duty became zero on the same clock (the
        firmware applies a demand at its next 20 ms control step: that wait, taken on the simulator's
        clock, added to the receipt), or ``moving``; ``none`` before any stop. A stop's way to the board
        is the robot's part of its latency."""
        model, world = self.sim.board.model, self.sim.world
        received, received_sim, zero_since = model.stop_received, model.stop_received_sim, world.zero_duty_since
        if received < 0:
            return "none"
        if zero_since < received_sim:
            return f"{received:.6f} moving"
        return f"{received:.6f} {received + zero_since - received_sim:.6f}"

    def close(self) -> None:
        self.sim.close()


# ---------------------------------------------------------------------------------------- supervisor

PI3B_MEMORY_MIB = 925
"""What a Raspberry Pi 3B's Linux has of its 1 GB, the GPU's share taken out: `free -m`'s total on a
Pi 3 Model B (andythemoron.com/blog/2017-04-23/Understanding-Linux-Memory-Usage). The box (its own
systemd, the robot and a student's programs) gets this much, as a cgroup's limit (docs/box.md)."""


def memory_group(name: str) -> tuple[Path, str]:
    """The box's memory cgroup (cgroup v1's memory controller, as on this machine, or v2's) and its
    limit's file. BoxError in one line when this machine has neither."""
    v1, v2 = Path("/sys/fs/cgroup/memory"), Path("/sys/fs/cgroup")
    if (v1 / "cgroup.procs").exists():
        return v1 / f"icefloe-box-{name}", "memory.limit_in_bytes"
    if (v2 / "cgroup.controllers").exists() and "memory" in (v2 / "cgroup.controllers").read_text().split():
        return v2 / f"icefloe-box-{name}", "memory.max"
    raise BoxError("this machine has no memory cgroup controller to limit the box with (--memory 0 boots "
                   "it without a limit)")


def memory_cgroup(name: str, mib: int) -> Path:
    """The box's memory cgroup, made with a limit of ``mib`` MiB; its ``cgroup.procs``."""
    group, limit_file = memory_group(name)
    try:
        if limit_file == "memory.max":
            with contextlib.suppress(OSError):
                (group.parent / "cgroup.subtree_control").write_text("+memory")
        group.mkdir(exist_ok=True)
        (group / limit_file).write_text(str(mib << 20))
    except OSError as exc:
        raise BoxError(f"cannot limit the box's memory to {mib} MiB in {group}: {exc} (--memory 0 boots it "
                       "without a limit)") from None
    return group / "cgroup.procs"


def box_cgroup(state: State) -> Path | None:
    """The ``cgroup.procs`` of the running box's memory limit, if it has one: what runs in the box from
    outside (`inside`: the install, a student's programs) joins it, as the box's own processes are in it."""
    if not state.read().get("memory"):
        return None
    procs = memory_group(state.read().get("name", ""))[0] / "cgroup.procs"
    return procs if procs.exists() else None


BOARD_NICE = -10
"""The supervisor's (the board's) nice value on this machine; the box runs at 0."""


def in_cgroup(procs: Path | None, command: list[str]) -> list[str]:
    """``command`` at nice 0 (the supervisor runs at `BOARD_NICE`), started inside the cgroup whose
    ``cgroup.procs`` is ``procs`` if one is given (before it runs: its every child is then in it too)."""
    join = f"echo $$ > {shlex.quote(str(procs))} && " if procs is not None else ""
    back = -os.getpriority(os.PRIO_PROCESS, 0)
    return ["sh", "-c", f'{join}exec nice -n {back} "$@"', "sh", *command]


def nspawn_command(state: State, cache: Path, name: str) -> list[str]:
    return ["systemd-nspawn", "--register=no", "--keep-unit", "--boot", f"--machine={name}",
            f"--directory={state.root}", "--console=read-only",
            # nspawn's system call filter allows mlock() only to a box with CAP_IPC_LOCK; a Pi
            # allows it within RLIMIT_MEMLOCK (Zenoh's shared memory locks its segments, hwbridge's
            # cycle its memory). The services, run as icefloe, do not get the capability itself.
            "--capability=CAP_IPC_LOCK",
            f"--bind={cache / 'pip'}:{BOX_PIP}", f"--bind={cache / 'apt'}:{BOX_APT}",
            f"--bind-ro={wheels_dir(cache, state.read().get('arch', 'amd64'))}:{BOX_WHEELS}"]


def container_init(nspawn_pid: int, timeout: float = 60.0) -> int:
    """PID (on the host) of the box's systemd: the first ``systemd`` below systemd-nspawn."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        todo = [nspawn_pid]
        while todo:
            pid = todo.pop()
            with contextlib.suppress(OSError):
                if pid != nspawn_pid and Path(f"/proc/{pid}/comm").read_text().strip() == "systemd":
                    return pid
                for task in Path(f"/proc/{pid}/task").iterdir():
                    todo += [int(c) for c in (task / "children").read_text().split()]
        time.sleep(0.1)
    raise BoxError(f"the box's systemd did not start within {timeout:.0f} s")


class Supervisor:
    """Runs the box (systemd-nspawn, again after each reboot) and the board; answers on a socket."""

    def __init__(self, state: State, cache: Path, name: str) -> None:
        self.state, self.cache, self.name = state, cache, name
        self.board = Board(state)
        self.nspawn: subprocess.Popen[bytes] | None = None
        self.stopping = False
        self.boots = 0

    def serve(self) -> int:
        # The board is a chip of its own on a robot: here it shares the CPUs with the box, so it runs
        # ahead of the box's programs (a student's busy loops would slow the simulated firmware down,
        # which no real board suffers); the box itself is put back to nice 0 (`in_cgroup`).
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, 0, BOARD_NICE)
        with contextlib.suppress(FileNotFoundError):
            self.state.sock.unlink()
        server = socket.socket(socket.AF_UNIX)
        server.bind(str(self.state.sock))
        os.chmod(self.state.sock, 0o600)
        server.listen(8)
        threading.Thread(target=self._accept, args=(server,), daemon=True).start()
        signal.signal(signal.SIGTERM, lambda *_: self.stop())
        signal.signal(signal.SIGINT, lambda *_: self.stop())
        status = 0
        try:
            while not self.stopping:
                status = self._boot_once()
                if status != REBOOT_STATUS:
                    break
                say("the box rebooted")
        finally:
            self.board.close()
            server.close()
            self.state.write(leader=0, running=False, status=status)
        return status

    def _boot_once(self) -> int:
        with self.state.console.open("ab") as console:
            mib = self.state.read().get("memory", 0)
            procs = memory_cgroup(self.name, mib) if mib else None
            self.nspawn = subprocess.Popen(in_cgroup(procs, nspawn_command(self.state, self.cache, self.name)),
                                           stdin=subprocess.DEVNULL, stdout=console, stderr=console)
            try:
                leader = container_init(self.nspawn.pid, 60 * slower(self.state))
                self.boots += 1
                self.state.write(leader=leader, boots=self.boots, running=True, nspawn=self.nspawn.pid)
                # The box's /dev is made at each boot: wait for it, then plug the board in.
                deadline = time.monotonic() + 30
                while not Path(f"/proc/{leader}/root/dev/pts/ptmx").exists() and time.monotonic() < deadline:
                    time.sleep(0.05)
                self.board.plug(leader)
            except BoxError as exc:
                say(str(exc))
                self.nspawn.terminate()
            return self.nspawn.wait()

    def stop(self) -> None:
        self.stopping = True
        if self.nspawn is not None and self.nspawn.poll() is None:
            if emulated(self.state.read().get("arch", "")):
                # nspawn asks for a power-off with SIGRTMIN+4, but qemu-user shifts the real-time signals
                # it hands its guest (it keeps some for itself): the box's systemd saw rescue mode's.
                with contextlib.suppress(BoxError, subprocess.TimeoutExpired):
                    if inside(self.state, "systemctl poweroff --no-block", capture=True, timeout=120).returncode == 0:
                        return
            self.nspawn.terminate()  # nspawn asks the box's systemd to power off

    def _accept(self, server: socket.socket) -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            with conn:
                try:
                    line = conn.makefile().readline().split()
                    reply = self.handle(line)
                except Exception as exc:  # any failure is the client's answer
                    reply = f"error {exc}"
                with contextlib.suppress(OSError):
                    conn.sendall(reply.encode() + b"\n")

    def handle(self, words: list[str]) -> str:
        """``pose`` (x y theta, m and rad: the simulator's truth), ``unplug``, ``plug``, ``stopped``
        (since when both wheels' duty is zero), ``received`` (when the last stop reached the board),
        ``stop`` (the box)."""
        match words:
            case ["pose"]:
                return self.board.pose()
            case ["unplug"]:
                self.board.unplug()
                return "unplugged"
            case ["plug"]:
                return "plugged " + self.board.plug(self.state.read()["leader"])
            case ["stopped"]:
                return self.board.stopped()
            case ["received"]:
                return self.board.received()
            case ["stop"]:
                self.stop()
                return "stopping"
        return f"error unknown request {' '.join(words)!r}: pose, unplug, plug, stopped, received, stop"


# ---------------------------------------------------------------------------------------- commands

def leader_of(state: State) -> int:
    info = state.read()
    leader = int(info.get("leader") or 0)
    if not leader or not Path(f"/proc/{leader}").exists():
        raise BoxError(f"no box is running in {state.dir}: deploy/box.sh up")
    return leader


def inside(state: State, command: str, user: str = "root", check: bool = False,
           capture: bool = False, timeout: float | None = None) -> subprocess.CompletedProcess[str]:
    """Run a shell command in the box, as ``user`` in a login shell (as over ssh)."""
    leader = leader_of(state)
    login = ["runuser", "-l", user, "-c", command] if user != "root" else ["bash", "-lc", command]
    argv = ["nsenter", f"--target={leader}", "--mount", "--uts", "--ipc", "--pid", "--",
            "env", "-i", f"PATH={PATH}", "LANG=C.UTF-8", "TERM=dumb", *login]
    if (procs := box_cgroup(state)) is not None:
        argv = ["sh", "-c", f'echo $$ > {shlex.quote(str(procs))} && exec "$@"', "sh", *argv]
    result = subprocess.run(argv, text=True, capture_output=capture, timeout=timeout, check=False)
    if check and result.returncode != 0:
        detail = f": {(result.stderr or result.stdout).strip()[-2000:]}" if capture else ""
        raise BoxError(f"in the box, as {user}: `{command}` exited {result.returncode}{detail}")
    return result


def wait_booted(state: State, timeout: float = 120.0) -> None:
    """Until the box's systemd has finished starting (running, or degraded: a unit failed)."""
    timeout *= slower(state)
    deadline = time.monotonic() + timeout
    last = ""
    while time.monotonic() < deadline:
        info = state.read()
        if info.get("running") is False:
            raise BoxError(f"the box stopped (status {info.get('status')}): see {state.console}")
        if info.get("leader"):
            with contextlib.suppress(BoxError, subprocess.TimeoutExpired):
                r = inside(state, "systemctl is-system-running", capture=True, timeout=20 * slower(state))
                last = r.stdout.strip()
                if last in ("running", "degraded"):
                    return
        time.sleep(0.5)
    raise BoxError(f"the box did not finish booting within {timeout:.0f} s (systemd: {last or '?'}); "
                   f"see {state.console}")


def port_free(port: int) -> bool:
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("0.0.0.0", port))
        except OSError:
            return False
    return True


def robot_ports(robot: str) -> list[int]:
    """The TCP ports the robot's router and web API take on this machine (the box shares its network)."""
    from icefloe import config as config_mod

    cfg = config_mod.load(robot)
    ports = [int(e.rsplit(":", 1)[1]) for e in cfg.zenoh.listen if e.startswith("tcp/")]
    return [*ports, cfg.webapi.port]


def mount_overlay(state: State, lower: Path) -> None:
    for d in (state.upper, state.work, state.root):
        d.mkdir(parents=True, exist_ok=True)
    if os.path.ismount(state.root):
        return
    opts = f"lowerdir={lower},upperdir={state.upper},workdir={state.work}"
    r = subprocess.run(["mount", "-t", "overlay", "overlay", "-o", opts, str(state.root)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise BoxError(f"cannot mount the box's copy of {lower} (overlay): {r.stderr.strip()}")


def cmd_up(args: argparse.Namespace, state: State) -> int:
    if state.read().get("running") and Path(f"/proc/{state.read().get('leader', 0)}").exists():
        raise BoxError(f"a box is already running in {state.dir}: deploy/box.sh down first")
    busy = [p for p in robot_ports(args.robot) if not port_free(p)]
    if busy:
        raise BoxError(f"port {', '.join(map(str, busy))} on this machine is in use, and the box shares "
                       f"this machine's network: stop what uses it (a robot running here?) and try again")
    emulation(args.arch, setuid=True)
    lower = build(args.cache, args.arch)
    wheelhouse(args.repo, wheels_dir(args.cache, args.arch), args.arch, args.rev)
    shutil.rmtree(state.dir, ignore_errors=True)
    state.dir.mkdir(parents=True, mode=0o700)
    for cache in ("pip", "apt", "wheels"):
        (args.cache / cache).mkdir(exist_ok=True)
    (args.cache / "apt" / "partial").mkdir(exist_ok=True)
    # pi and root both fill the pip cache: let either use what the other put there
    subprocess.run(["chmod", "-R", "a+rwX", str(args.cache / "pip")], check=False)
    mount_overlay(state, lower)
    # Box infrastructure (not the robot's): where pip and apt keep what they downloaded; apt keeps
    # its downloads (Debian's docker-clean rule would delete them); the repository as a bundle.
    (state.root / "etc/pip.conf").write_text(f"[global]\ncache-dir = {BOX_PIP}\nfind-links = {BOX_WHEELS}\n")
    (state.root / "etc/apt/apt.conf.d/99icefloe-box").write_text('Binary::apt::APT::Keep-Downloaded-Packages "true";\n')
    # Raspberry Pi OS names the machine in /etc/hosts (sudo looks its name up); so does the box
    (state.root / "etc/hosts").write_text(f"127.0.0.1\tlocalhost\n::1\t\tlocalhost ip6-localhost ip6-loopback\n"
                                          f"127.0.1.1\traspberrypi {args.name}\n")
    if emulated(args.arch):
        # qemu-user lacks the mount calls systemd sets a unit's credentials up with (EINVAL): Debian's
        # tmpfiles and sysusers units, which load optional ones, fail at boot, and with them every
        # tmpfiles.d folder (the robot's /run/icefloe). Box infrastructure: they load none here.
        for unit in ("systemd-tmpfiles-setup", "systemd-tmpfiles-setup-dev", "systemd-sysusers"):
            dropin = state.root / f"etc/systemd/system/{unit}.service.d"
            dropin.mkdir(parents=True, exist_ok=True)
            (dropin / "icefloe-box-qemu.conf").write_text("[Service]\nLoadCredential=\n")
    bundle = state.root / "var/tmp/icefloe.bundle"
    r = subprocess.run(["git", "-C", str(args.repo), "bundle", "create", str(bundle), args.rev],
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise BoxError(f"cannot bundle {args.repo} at {args.rev}: {r.stderr.strip()}")
    state.write(name=args.name, cache=str(args.cache), arch=args.arch, robot=args.robot, running=False,
                memory=args.memory,
                rev=subprocess.run(["git", "-C", str(args.repo), "rev-parse", args.rev],
                                   capture_output=True, text=True).stdout.strip())
    start = time.monotonic()
    log = (state.dir / "supervisor.log").open("ab")
    subprocess.Popen([sys.executable, __file__, "--dir", str(state.dir), "--cache", str(args.cache),
                      "--name", args.name, "serve"],
                     stdin=subprocess.DEVNULL, stdout=log, stderr=log, start_new_session=True, cwd=REPO)
    deadline = time.monotonic() + 60 * SLOWER.get(args.arch, 1.0)
    while not state.read().get("leader"):
        if time.monotonic() > deadline:
            raise BoxError(f"the box did not start: see {state.dir / 'supervisor.log'}")
        time.sleep(0.2)
    wait_booted(state)
    say(f"booted in {time.monotonic() - start:.0f} s ({state.dir})")
    make_pi(state)
    if not args.no_install:
        install(state, args.robot)
    return 0


def make_pi(state: State) -> None:
    """What a Raspberry Pi's first boot makes: the user pi (home 0700, Debian's default), in sudo; and
    the repository cloned into its home, as the TA does (from a bundle of the checkout's commit)."""
    inside(state, "id -u pi >/dev/null 2>&1 || adduser --disabled-password --gecos '' pi >/dev/null && "
                  "usermod -aG sudo,dialout,video pi && "
                  # Box infrastructure: the TA would type pi's password to sudo.
                  "echo 'pi ALL=(ALL) NOPASSWD: ALL' > /etc/sudoers.d/010_pi-nopasswd && "
                  "chmod 0440 /etc/sudoers.d/010_pi-nopasswd && chmod 0700 /home/pi", check=True, capture=True)
    inside(state, "test -d icefloe || git -c advice.detachedHead=false clone -q /var/tmp/icefloe.bundle icefloe",
           user="pi", check=True, capture=True)
    say("user pi (home 0700, sudo) with the repository in /home/pi/icefloe")


INSTALL = f"./deploy/up.sh {{robot}} --install --no-boot-config --wheelhouse={BOX_WHEELS}"
"""The install as the TA runs it on a Pi, with the box's explicit differences (docs/box.md), from the box's
wheelhouse: the lock's files only, nothing downloaded (the install refuses a wheelhouse that is not the lock's)."""


def install(state: State, robot: str) -> None:
    start = time.monotonic()
    command = INSTALL.format(robot=robot)
    say(f"as pi in ~/icefloe: {command}")
    r = inside(state, f"cd ~/icefloe && {command}", user="pi", capture=True)
    (state.dir / "install.log").write_text(r.stdout + r.stderr)
    if r.returncode != 0:
        tail = "\n".join((r.stdout + r.stderr).strip().splitlines()[-15:])
        raise BoxError(f"the install failed (exit {r.returncode}; {state.dir / 'install.log'}):\n{tail}")
    say(f"installed in {time.monotonic() - start:.0f} s")
    copy_credentials(state, robot)


def copy_credentials(state: State, robot: str) -> Path | None:
    """The robot's credentials file, copied out (0600) as the TA hands it to whoever drives the robot."""
    src = state.root / f"etc/icefloe/{robot}.credentials"
    if not src.exists():
        return None
    dst = state.dir / f"{robot}.credentials"
    shutil.copy(src, dst)
    os.chmod(dst, 0o600)
    say(f"the owner's credentials: {dst}  (icefloe status --credentials {dst})")
    return dst


def cmd_down(state: State) -> int:
    info = state.read()
    if info.get("running"):
        with contextlib.suppress(BoxError):
            ask(state, "stop")
        deadline = time.monotonic() + 60 * slower(state)
        while state.read().get("running") and time.monotonic() < deadline:
            time.sleep(0.2)
        if state.read().get("running"):
            raise BoxError(f"the box did not power off within {60 * slower(state):.0f} s: see {state.console}")
    if os.path.ismount(state.root):
        subprocess.run(["umount", str(state.root)], check=False)
    if info.get("memory"):
        with contextlib.suppress(OSError, BoxError):  # empty once the box is off
            memory_group(info.get("name", ""))[0].rmdir()
    shutil.rmtree(state.dir, ignore_errors=True)
    say(f"box in {state.dir} powered off and removed")
    return 0


def cmd_reboot(state: State) -> int:
    boots = state.read().get("boots", 0)
    inside(state, "systemctl reboot", capture=True)
    deadline = time.monotonic() + 120 * slower(state)
    while state.read().get("boots", 0) == boots:
        if time.monotonic() > deadline or state.read().get("running") is False:
            raise BoxError(f"the box did not come back from the reboot: see {state.console}")
        time.sleep(0.2)
    wait_booted(state)
    say("rebooted")
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="deploy/box.sh", description=__doc__.split("\n\n")[0])
    p.add_argument("--cache", type=Path, default=Path(os.environ.get("ICEFLOE_BOX_CACHE", "/var/cache/icefloe/box")),
                   help="where the built root and the pip/apt caches live (default /var/cache/icefloe/box, "
                        "or $ICEFLOE_BOX_CACHE)")
    p.add_argument("--dir", type=Path, default=Path(os.environ.get("ICEFLOE_BOX_DIR", "/var/tmp/icefloe-box")),
                   help="the running box's folder: its copy of the root, logs, credentials "
                        "(default /var/tmp/icefloe-box, or $ICEFLOE_BOX_DIR)")
    p.add_argument("--arch", default="amd64", choices=["amd64", "arm64"],
                   help="the box's architecture (arm64: emulated by qemu-user-static, slow)")
    p.add_argument("--name", default="icefloe-box", help="the box's machine name")
    sub = p.add_subparsers(dest="command")
    up = sub.add_parser("up", help="boot a fresh box and install the robot as pi (the default)")
    up.add_argument("--repo", type=Path, default=REPO, help="the repository to clone into the box (default: this one)")
    up.add_argument("--rev", default="HEAD", help="its commit to clone (default HEAD: committed work only)")
    up.add_argument("--robot", default="penguin1", help="the robot config to install (default penguin1)")
    up.add_argument("--no-install", action="store_true", help="stop after making pi and cloning the repository")
    up.add_argument("--memory", type=int, default=PI3B_MEMORY_MIB, metavar="MIB",
                    help=f"the box's memory limit, MiB (default {PI3B_MEMORY_MIB}: what a Raspberry Pi 3B has; "
                         "0: none)")
    sub.add_parser("build", help="make the cached root and the wheelhouse (if missing)").add_argument(
        "--rebuild", action="store_true", help="make the root again even if it exists")
    inst = sub.add_parser("install", help="run the install as pi again")
    inst.add_argument("--robot", default="penguin1", help="the robot config (default penguin1)")
    ex = sub.add_parser("exec", help="run a shell command in the box")
    ex.add_argument("--user", default="root", help="as this user, in a login shell (default root)")
    ex.add_argument("cmd", nargs=argparse.REMAINDER, help="the command (after --)")
    bd = sub.add_parser("board", help="the board outside the box")
    bd.add_argument("action", choices=["pose", "unplug", "plug", "stopped", "received"],
                    help="pose: the simulator's truth (x y theta, m, rad); unplug/plug the serial line; "
                         "stopped: since when both wheels' duty is zero (this machine's monotonic clock, s) or "
                         "'moving'; received: when the last stop reached the board and when its duty became "
                         "zero (the same clock; 'moving' until it is) or 'none'")
    sub.add_parser("reboot", help="reboot the box (systemctl reboot inside) and wait until it is up")
    sub.add_parser("down", help="power the box off and throw its copy away")
    sub.add_parser("serve", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    args.cache = args.cache.resolve()
    state = State(args.dir.resolve())
    try:
        if os.geteuid() != 0:
            raise BoxError("run as root (sudo deploy/box.sh): booting a box needs it")
        match args.command:
            case "build":
                build(args.cache, args.arch, args.rebuild)
                wheelhouse(REPO, wheels_dir(args.cache, args.arch), args.arch)
                return 0
            case "serve":
                return Supervisor(state, args.cache, args.name).serve()
            case "up" | None:
                if args.command is None:
                    args = p.parse_args([*(argv or sys.argv[1:]), "up"])
                    args.cache = args.cache.resolve()
                return cmd_up(args, state)
            case "install":
                install(state, args.robot)
                return 0
            case "exec":
                cmd = args.cmd[1:] if args.cmd[:1] == ["--"] else args.cmd
                return inside(state, shlex.join(cmd) if len(cmd) > 1 else "".join(cmd), user=args.user).returncode
            case "board":
                print(ask(state, args.action))
                return 0
            case "reboot":
                return cmd_reboot(state)
            case "down":
                return cmd_down(state)
    except BoxError as exc:
        print(f"box: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
