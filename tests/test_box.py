"""The robot in a box (deploy/box.sh, docs/box.md): a fresh Debian bookworm booted with
systemd-nspawn, where the robot is installed as a TA installs it on a Raspberry Pi, with the
simulated PenguinPi board outside the box on a pseudo-terminal linked in as /dev/serial0.

One box for the whole file (it boots twice: once fresh, once after the install); the tests run in
order, each on the state the one before left (issue 25's checks, numbered as there). Needs root,
systemd-nspawn and debootstrap (tests/run.sh installs them), and this machine's ports 7447 and 8080
(the box shares its network). The first run builds the cached root (~6 min); later ones reuse it.

ICEFLOE_BOX_ARCH=arm64 runs the same checks in an arm64 box (qemu-user-static; on request only, far
slower: every wait below is SLOW times longer; docs/box.md has a measured run). Each arch's run keeps the
robot venv's `pip freeze` in the box's cache folder, and compares it with the other arch's, if there is one
for the same lock.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import time
import urllib.error
import urllib.request
from base64 import b64encode
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import pytest
from conftest import ROOT
from packaging.utils import canonicalize_name

from icefloe import lock
from icefloe.credentials import read as read_credentials
from icefloe.deploy import SERVICE_ENV

BOX = ROOT / "deploy" / "box.sh"
ICEFLOE = ROOT / ".venv" / "bin" / "icefloe"
ROBOT = "penguin1"
SERVICES = ["info", "hwbridge", "odometry", "localizer", "power", "oled", "webapi"]
"""penguin1's services that run in the box (the camera has no picamera2 here: check 5)."""
UNITS = ["icefloe-router.service", "icefloe-hwbridge.service",
         *(f"icefloe@{s}.service" for s in SERVICES if s != "hwbridge")]
FORKSERVER = "icefloe-forkserver.service"
"""Root's (the services' units are icefloe's): it starts every unit's service as a copy of itself."""
PORTS = (7447, 8080)
ROUTER = "tcp/127.0.0.1:7447"
WEBAPI = "http://127.0.0.1:8080"
ARCH = os.environ.get("ICEFLOE_BOX_ARCH", "amd64")
CACHE = Path(os.environ.get("ICEFLOE_BOX_CACHE", "/var/cache/icefloe/box"))
"""deploy/box.sh's cache folder (its default, as the test runs it): the freeze files of each arch go there."""
SLOW = {"amd64": 1, "arm64": 6}.get(ARCH, 1)
"""Every timeout of this file is this many times longer in a box whose programs qemu emulates."""
T = TypeVar("T")


def _why_not() -> str:
    if os.environ.get("ICEFLOE_BOX") != "1":
        # It needs this machine's ports 7447 and 8080, which other tests' documented commands use:
        # ./tests/run.sh runs it after the rest of the suite, on its own (docs/box.md).
        return ("the robot in a box runs after the rest of ./tests/run.sh, or alone: "
                "ICEFLOE_BOX=1 .venv/bin/pytest tests/test_box.py")
    if os.geteuid() != 0:
        return "needs root (systemd-nspawn boots the box)"
    if ARCH not in ("amd64", "arm64"):
        return f"ICEFLOE_BOX_ARCH={ARCH}: the box is amd64 or arm64"
    for tool, package in (("systemd-nspawn", "systemd-container"), ("debootstrap", "debootstrap")):
        if not shutil.which(tool):
            return f"needs {tool} (apt-get install {package}; tests/run.sh does)"
    return ""


pytestmark = [pytest.mark.slow, pytest.mark.timeout(2400 * SLOW),
              pytest.mark.skipif(bool(_why_not()), reason=_why_not() or "-")]


def _port_busy(port: int) -> bool:
    return not _box_module().port_free(port)


@functools.cache
def _box_module():  # type: ignore[no-untyped-def]
    """deploy/box/box.py itself (a script, not a package): its port check is the one `up` makes."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("icefloe_box", ROOT / "deploy" / "box" / "box.py")
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


class Box:
    """deploy/box.sh on one box folder."""

    def __init__(self, folder: Path) -> None:
        self.dir = folder
        self.credentials = folder / f"{ROBOT}.credentials"

    def sh(self, *args: str, timeout: float = 900, check: bool = True) -> subprocess.CompletedProcess[str]:
        r = subprocess.run([str(BOX), "--dir", str(self.dir), "--name", "icefloe-test", "--arch", ARCH, *args],
                           capture_output=True, text=True, timeout=timeout * SLOW, cwd=ROOT)
        if check and r.returncode != 0:
            raise AssertionError(f"deploy/box.sh {' '.join(args)} exited {r.returncode}:\n{r.stdout}\n{r.stderr}")
        return r

    def run(self, command: str, user: str = "root", timeout: float = 120,
            check: bool = True) -> subprocess.CompletedProcess[str]:
        """A shell command in the box (a login shell of ``user``)."""
        return self.sh("exec", "--user", user, "--", command, timeout=timeout, check=check)

    def pose(self) -> tuple[float, float, float]:
        x, y, theta = self.sh("board", "pose").stdout.split()
        return float(x), float(y), float(theta)

    def board(self, action: str) -> str:
        return self.sh("board", action).stdout.strip()

    def units(self, *extra: str) -> dict[str, dict[str, str]]:
        names = " ".join([*UNITS, "icefloe@camera.service", *extra])
        out = self.run(f"systemctl show -p Id,ActiveState,SubState,MainPID,Result,NRestarts,ExecMainStatus {names}"
                       ).stdout
        result: dict[str, dict[str, str]] = {}
        for block in out.strip().split("\n\n"):
            fields = dict(line.split("=", 1) for line in block.splitlines() if "=" in line)
            result[fields["Id"]] = fields
        return result


def wait_for(what: str, condition: Callable[[], T], timeout: float, every: float = 1.0) -> T:
    timeout *= SLOW
    deadline = time.monotonic() + timeout
    last = None
    while time.monotonic() < deadline:
        last = condition()
        if last:
            return last
        time.sleep(every)
    raise AssertionError(f"{what}: not within {timeout:.0f} s (last: {last!r})")


@pytest.fixture(scope="module")
def box(tmp_path_factory: pytest.TempPathFactory):
    busy = [p for p in PORTS if _port_busy(p)]
    if busy:  # another robot on this machine (the box shares its network): wait a while for it
        try:
            wait_for(f"ports {busy} free", lambda: not any(_port_busy(p) for p in PORTS), 120, 2)
        except AssertionError:
            pytest.fail(f"ports {busy} of this machine are in use: the box's robot needs them "
                        "(another robot or box running here?)")
    b = Box(Path(tmp_path_factory.mktemp("box")) / "box")
    start = time.monotonic()
    b.sh("up", "--no-install", timeout=1200)
    print(f"box up (and root built if missing) in {time.monotonic() - start:.0f} s")
    try:
        yield b
    finally:
        print(b.sh("down", check=False).stdout)


def test_1_readme_first_command_as_a_new_user(box: Box) -> None:
    # A fresh Debian with python3 and python3-venv, no compiler, no Python headers.
    box.run("! command -v gcc && ! command -v cc && ! ls /usr/include/python3*/Python.h")
    box.run("adduser --disabled-password --gecos '' student >/dev/null")
    box.run("git -c advice.detachedHead=false clone -q /var/tmp/icefloe.bundle icefloe && cd icefloe && "
            "(setsid ./deploy/up.sh --no-viz > ~/up.log 2>&1 & echo $! > ~/up.pid)", user="student")

    def up() -> str:
        r = box.run("cd icefloe && test -x .venv/bin/icefloe && .venv/bin/icefloe status", user="student",
                    check=False)
        alive = all(s in r.stdout for s in ("hwbridge", "odometry", "webapi", "sim"))
        failed = box.run("! kill -0 $(cat ~/up.pid) 2>/dev/null && tail -20 ~/up.log", user="student",
                         check=False)
        if failed.returncode == 0:
            raise AssertionError(f"./deploy/up.sh --no-viz stopped:\n{failed.stdout}")
        return r.stdout if alive else ""

    print(wait_for("the README's robot up", up, 900, 5))
    box.run("kill -INT -- -$(cat ~/up.pid); for i in $(seq 60); do kill -0 $(cat ~/up.pid) 2>/dev/null || exit 0; "
            "sleep 0.5; done; exit 1", user="student")
    assert "all stopped" in box.run("tail -3 ~/up.log", user="student").stdout


INSTALLED = "/opt/icefloe /etc/icefloe /etc/systemd/system /etc/udev/rules.d /etc/tmpfiles.d"
"""The folders the robot install writes into."""


def _install_command(wheelhouse: str = "") -> str:
    """The robot install as the box runs it (deploy/box/box.py's INSTALL: from the box's wheelhouse, the
    lock's files), or from another ``wheelhouse``."""
    command = _box_module().INSTALL.format(robot=ROBOT)
    if wheelhouse:
        command = command.replace(f"--wheelhouse={_box_module().BOX_WHEELS}", f"--wheelhouse={wheelhouse}")
    return f"cd ~/icefloe && {command}"


def _install_snapshot(box: Box) -> str:
    """What the install wrote: every file under its folders with its hash, mode and owner."""
    return box.run(f"find {INSTALLED} "
                   "-newer /etc/hostname \\( -type f -o -type l \\) -not -name '*.pyc' "
                   "-exec stat -c '%n %a %U' {} + | sort; "
                   "md5sum $(find /etc/icefloe /etc/systemd/system /etc/udev/rules.d /etc/tmpfiles.d -type f) "
                   "| sort").stdout


def test_1_install_as_pi_from_a_0700_home_twice(box: Box) -> None:
    assert box.run("stat -c %a ~", user="pi").stdout.strip() == "700"
    start = time.monotonic()
    out = box.sh("install", timeout=1500).stdout
    print(f"first install: {time.monotonic() - start:.0f} s")
    assert box.credentials.exists(), out
    before = _install_snapshot(box)
    start = time.monotonic()
    again = box.run(_install_command(), user="pi", timeout=900).stdout
    print(f"second install: {time.monotonic() - start:.0f} s")
    assert "Done: 0 steps changed something." in again, again
    assert _install_snapshot(box) == before


NOT_THE_LOCKS = "/var/tmp/not-the-locks-wheels"
"""A copy of the box's wheelhouse (symbolic links to its files) with one file replaced or missing."""


def _main_pids(box: Box) -> dict[str, str]:
    units = box.units()
    return {unit: units[unit]["MainPID"] for unit in UNITS}


def _refused(box: Box, change: str) -> str:
    """The robot install given the box's wheelhouse changed by the shell command ``change`` (in
    `NOT_THE_LOCKS`): what it said, once it is refused and nothing on the box changed."""
    box.run(f"rm -rf {NOT_THE_LOCKS} && mkdir {NOT_THE_LOCKS} && cd {NOT_THE_LOCKS} && "
            f"cp -s {_box_module().BOX_WHEELS}/*.whl . && {change}")
    before, pids = _install_snapshot(box), _main_pids(box)
    box.run("touch /var/tmp/before-the-refusal")
    r = box.run(_install_command(NOT_THE_LOCKS), user="pi", check=False)
    assert r.returncode != 0, f"the install took a wheelhouse that is not the lock's:\n{r.stdout}"
    changed = box.run(f"find {INSTALLED} /var/lib/icefloe -newer /var/tmp/before-the-refusal").stdout
    assert changed == "", f"the refused install changed:\n{changed}"
    assert _install_snapshot(box) == before
    assert _main_pids(box) == pids, "a unit restarted"
    assert r.stdout == "" and len(r.stderr.splitlines()) == 1, (r.stdout, r.stderr)  # one line
    print(r.stderr.strip())
    return r.stderr


def test_1_a_wheelhouse_not_the_locks_is_refused_and_nothing_changes(box: Box) -> None:
    # another version: bookworm's own pip wheel (the venv's, from python3-venv) for the lock's
    said = _refused(box, "rm pip-*.whl && cp /usr/share/python-wheels/pip-*.whl .")
    assert re.search(r": pip [\d.]+: pip-23[\d.]+-py3-none-any.whl is not a file the lock lists", said), said
    said = _refused(box, "rm smbus2-*.whl")  # a package missing (luma.oled's, for the OLED)
    assert re.search(rf": smbus2 [\d.]+: no file in {NOT_THE_LOCKS}$", said.strip()), said


def _lock_digest() -> str:
    """What identifies the robot install's lock (deploy/requirements: build.txt, robot.txt) at HEAD."""
    h = hashlib.sha256()
    for name in ("build", "robot"):
        h.update(subprocess.run(["git", "show", f"HEAD:deploy/requirements/{name}.txt"], capture_output=True,
                                check=True, cwd=ROOT).stdout)
    return h.hexdigest()[:16]


def test_1_the_robots_venv_is_the_lock_on_this_arch(box: Box) -> None:
    """The robot's venv, installed from the wheelhouse: `pip freeze` is the lock's pins for the box's
    machine (every file's hash checked by pip's --require-hashes), and the same as the other arch's box
    made from the same lock, when one ran here before (its freeze file is kept in the cache folder)."""
    freeze = box.run("/opt/icefloe/venv/bin/python -m pip freeze --local --all").stdout.splitlines()
    freeze = sorted(line for line in freeze if not line.startswith("icefloe"))
    machine = _box_module().MACHINE[ARCH]
    locked = lock.pins(["build", "robot"], environment=lock.environment(machine, _box_module().BOX_PYTHON))
    pinned = sorted((canonicalize_name(name), version) for name, _, version in (x.partition("==") for x in freeze))
    assert pinned == [(name, pin.version) for name, pin in sorted(locked.items())], freeze
    checked = box.run("/opt/icefloe/venv/bin/python -m icefloe.lock", check=False)
    assert checked.returncode == 0 and "every installed package is as locked" in checked.stdout, checked.stdout
    mine = CACHE / f"freeze-{_lock_digest()}-{ARCH}.txt"
    mine.write_text("\n".join(freeze) + "\n")
    print(f"the robot's venv ({len(freeze)} packages, {machine}) in {mine}")
    for other in sorted(CACHE.glob(f"freeze-{_lock_digest()}-*.txt")):
        if other != mine:
            assert other.read_text() == mine.read_text(), f"{other} and {mine} differ"
            print(f"the same as {other}")


def test_2_after_a_reboot_every_unit_runs_as_icefloe(box: Box) -> None:
    box.sh("reboot", timeout=300)

    def all_active() -> dict[str, dict[str, str]] | None:
        units = box.units()
        return units if all(units[u]["ActiveState"] == "active" for u in UNITS) else None

    units = wait_for("every unit active", all_active, 120, 2)
    for unit in UNITS:
        user = box.run(f"ps -o user= -p {units[unit]['MainPID']}").stdout.strip()
        assert user == "icefloe", (unit, user)
        # The unit's environment is the service's (the request carries it); /proc/<pid>/environ cannot
        # say so: a copy's is the fork server's memory, which setproctitle reused for the command line.
        environment = box.run(f"systemctl show -p Environment --value {unit}").stdout.split()
        assert {f"{k}={v}" for k, v in SERVICE_ENV.items()} <= set(environment), (unit, environment)
    # Every unit's process is a copy of the fork server (root, its own unit), made like its unit: the
    # user above, and the unit's cgroup (what systemd stops, restarts and accounts). docs/deploy.md, "Memory".
    server = box.units(FORKSERVER)[FORKSERVER]
    assert server["ActiveState"] == "active", server
    assert box.run(f"ps -o user= -p {server['MainPID']}").stdout.strip() == "root"
    # what glibc and OpenBLAS read once, at the start of a process: the fork server's, which the copies keep
    environment = box.run(f"systemctl show -p Environment --value {FORKSERVER}").stdout.split()
    assert {f"{k}={v}" for k, v in SERVICE_ENV.items()} <= set(environment), environment
    started = box.run("journalctl -b -u icefloe-forkserver --no-pager -o cat").stdout
    for unit in UNITS:
        pid = units[unit]["MainPID"]
        assert f" as pid {pid} for pid " in started, (unit, pid, started)
        cgroup = box.run(f"cat /proc/{pid}/cgroup").stdout
        assert f"/{unit}\n" in cgroup, (unit, cgroup)
    # hwbridge's cycle (its rt child process): SCHED_FIFO with memory locked, or one line saying so
    journal = box.run("journalctl -b -u icefloe-hwbridge --no-pager -o cat").stdout
    rt = box.run("pid=$(pgrep -u icefloe -f 'services[.]hwbridge[.]rt' | head -1) && chrt -p $pid && "
                 "grep VmLck /proc/$pid/status").stdout
    withheld = [line for line in journal.splitlines() if "real time withheld" in line]
    granted = "SCHED_FIFO" in rt and "VmLck:\t       0 kB" not in rt
    print(rt, *withheld, sep="\n")
    assert granted or len(withheld) == 1, (rt, journal)


def _status(box: Box, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(ICEFLOE), "status", *extra], capture_output=True, text=True, timeout=60 * SLOW,
                          cwd=ROOT)


def _owner(box: Box) -> list[str]:
    return ["--credentials", str(box.credentials)]


SPEED = 0.2
"""m/s of every drive (`_drives_a_metre`: 5 s, 1 m)."""
DRIVEN = 0.05
"""How far from 1 m a drive may end by the simulator's truth: 5 % (the timed motion, measured on an idle
machine, 2026-12-07: 0.989 to 0.997 m over the file's seven drives; docs/box.md)."""
GUEST = "connected as the read-only user 'guest': this session cannot command the robot"
"""What `icefloe pub` says when the robot's router wants credentials it was not given (runtime.open_session)."""
RETRYING = f"cannot reach a Zenoh router at {ROUTER} yet; retrying"
"""What a command says while the router is slow to open its session (a busy machine); then it goes on."""


def _speed_from(x: float) -> float:
    """`SPEED`, backwards when the robot is more than half a metre out (the lab's east wall stops its
    centre at x = 1.9 m; deploy/worlds/lab.toml keeps x in [-0.5, 1.4] m clear for 1 m drives)."""
    return -SPEED if x > 0.5 else SPEED


def _drive(box: Box, count: int, *credentials: str) -> tuple[float, subprocess.CompletedProcess[str]]:
    """``icefloe pub cmd/twist`` at `SPEED`, 10 a second, ``count`` times, from outside the box; the
    distance the simulator's truth moved, and what pub answered. The robot drives from the first command
    to the deadman's stop 0.5 s after the last: (count - 1) * 0.1 s + 0.5 s, back towards the start when
    it is more than half a metre out (`_speed_from`)."""
    x0, y0, _ = box.pose()
    twist = json.dumps({"v": _speed_from(x0), "w": 0.0})
    pub = subprocess.run([str(ICEFLOE), "pub", "cmd/twist", twist, "--rate", "10", "-n", str(count),
                          "--robot", ROBOT, *credentials], capture_output=True, text=True, timeout=120 * SLOW, cwd=ROOT)
    time.sleep(1.5)  # the deadman's stop, and standing still
    x1, y1, _ = wait_for("the robot standing still", lambda: _still(box), 30, 0)
    return ((x1 - x0) ** 2 + (y1 - y0) ** 2) ** 0.5, pub


def _drives_a_metre(box: Box, after: str) -> None:
    """The owner drives 1 m from outside, timed on the robot: ``icefloe query cmd/motion``, 5 s at
    `SPEED` (back towards the start when more than half a metre out, `_speed_from`); the simulator's truth
    says 1 m +- `DRIVEN`. (Not a stream of ``cmd/twist``: that drive lasts until the deadman's stop after
    the last command, so a stream the machine's load delays drives on: 1.063 m beside the suite.)"""
    x0, y0, _ = box.pose()
    speed = _speed_from(x0)
    motion = json.dumps({"left": speed, "right": speed, "duration": 1.0 / SPEED})
    ask = subprocess.run([str(ICEFLOE), "query", "cmd/motion", motion, "--timeout", str(30 * SLOW),
                          "--robot", ROBOT, *_owner(box)], capture_output=True, text=True, timeout=120 * SLOW, cwd=ROOT)
    assert ask.returncode == 0 and GUEST not in ask.stderr, (ask.stdout, ask.stderr)
    x1, y1, _ = wait_for("the robot standing still", lambda: _still(box), 30, 0)
    moved = ((x1 - x0) ** 2 + (y1 - y0) ** 2) ** 0.5
    print(f"{after}: drove {moved:.3f} m by the simulator's truth (asked 1 m)")
    assert abs(moved - 1.0) <= DRIVEN, f"{after}: drove {moved:.3f} m, asked 1 m"


def _still(box: Box) -> tuple[float, float, float] | None:
    """The simulator's truth if it did not change in half a second (an emulated hwbridge stops later)."""
    before = box.pose()
    time.sleep(0.5)
    after = box.pose()
    return after if max(abs(a - b) for a, b in zip(before, after, strict=True)) < 1e-6 else None


def test_3_from_outside_with_the_owners_credentials(box: Box) -> None:
    status = wait_for("icefloe status lists every service",
                      lambda: (r := _status(box, *_owner(box))).returncode == 0
                      and all(s in r.stdout for s in SERVICES) and r.stdout, 60, 2)
    print(status)
    # Nothing moves without credentials: pub logs in as the read-only guest, says that it cannot command
    # the robot, and ends as it should (no other line: it did not fail for another reason); the truth
    # says the robot stood still.
    moved, pub = _drive(box, 20, "--connect", ROUTER)
    print(f"without credentials: pub exited {pub.returncode}, said {pub.stderr.strip()!r}; moved {moved:.4f} m")
    assert pub.returncode == 0 and pub.stdout == "", (pub.returncode, pub.stdout, pub.stderr)
    said = pub.stderr.splitlines()
    assert said.count(GUEST) == 1 and set(said) <= {GUEST, RETRYING}, said
    assert moved < 0.005, f"the robot moved {moved:.3f} m without credentials"
    _drives_a_metre(box, "with the owner's credentials")
    # The old web API: a route that commands needs the owner's login; without it, 401
    owner = read_credentials(box.credentials)
    request = urllib.request.Request(f"{WEBAPI}/robot/stop")
    with pytest.raises(urllib.error.HTTPError) as no_login:
        urllib.request.urlopen(request, timeout=10)
    assert no_login.value.code == 401
    token = b64encode(f"{owner.user}:{owner.password}".encode()).decode()
    request.add_header("Authorization", f"Basic {token}")
    with urllib.request.urlopen(request, timeout=10) as answer:
        assert answer.status == 200


def _every_service_on_the_bus(box: Box) -> str:
    r = _status(box, *_owner(box))
    return r.stdout if r.returncode == 0 and all(s in r.stdout.split() for s in ["router", *SERVICES]) else ""


def _killed_and_restarted(box: Box, *units: str) -> None:
    """SIGKILL to every process of each of ``units`` at once: systemd starts each again (a new main
    process), and every service is back on the bus (the router's restart takes the others with it: they
    Require= it)."""
    before = box.units()
    box.run(f"systemctl kill -s KILL {' '.join(units)}")

    def not_restarted() -> list[str]:
        now = box.units()
        return [u for u in units
                if now[u]["ActiveState"] != "active" or now[u]["MainPID"] in ("0", before[u]["MainPID"])]

    try:
        wait_for(f"{', '.join(units)} restarted", lambda: not not_restarted(), 60, 1)
    except AssertionError:
        raise AssertionError(f"not restarted within {60 * SLOW} s of the SIGKILL: "
                             f"{', '.join(not_restarted())}") from None
    wait_for(f"every service on the bus after the SIGKILL of {', '.join(units)}",
             lambda: _every_service_on_the_bus(box), 60, 2)


def test_4_a_killed_hwbridge_restarts_and_the_robot_drives_again(box: Box) -> None:
    _killed_and_restarted(box, "icefloe-hwbridge.service")
    _drives_a_metre(box, "after hwbridge's SIGKILL")


def test_4_every_other_service_killed_restarts_and_the_robot_drives_again(box: Box) -> None:
    # The router first: the commands' path (it restarts every service with it); then every template
    # unit's instance at once (each its own process: each must restart). A drive after each: only the
    # router and hwbridge carry a command, and each instance's restart is checked on the bus.
    _killed_and_restarted(box, "icefloe-router.service")
    _drives_a_metre(box, "after the router's SIGKILL")
    instances = [unit for unit in UNITS if unit.startswith("icefloe@")]
    _killed_and_restarted(box, *instances)
    _drives_a_metre(box, f"after the SIGKILL of {', '.join(instances)}")


AWAY = Path(f"/run/systemd/system/{FORKSERVER}.d/icefloe-test-away.conf")


def test_4_without_the_fork_server_every_service_runs_and_restarts_on_its_own(box: Box) -> None:
    """The fork server stopped: the services it started run on (they are not its children); a killed
    service restarts as a fresh Python, saying so in one line; the robot drives. Then it is back."""
    before = box.units()
    stopped = box.run("date +%s.%N").stdout.strip()
    # Kept away, or a service's restart would start it again (the units want it); not by `mask --runtime`,
    # which /etc's unit file outranks: a runtime drop-in whose condition fails (the unit is then skipped).
    box.run(f"mkdir -p {AWAY.parent} && printf '[Unit]\\nConditionPathExists=/nonexistent\\n' > {AWAY} && "
            f"systemctl daemon-reload && systemctl stop {FORKSERVER}")
    try:
        after = box.units()
        assert all(after[u]["MainPID"] == before[u]["MainPID"] for u in UNITS), (before, after)
        _killed_and_restarted(box, "icefloe@odometry.service", "icefloe-hwbridge.service")
        alone = box.run(f"journalctl -u icefloe@odometry -u icefloe-hwbridge --since @{stopped} --no-pager -o cat "
                        "| grep 'did not start it'").stdout.strip().splitlines()
        assert len(alone) == 2 and all("starting it on its own" in line for line in alone), alone
        _drives_a_metre(box, "after hwbridge's restart without the fork server")
    finally:
        box.run(f"rm -f {AWAY} && systemctl daemon-reload && systemctl start {FORKSERVER}")


def _hwbridge_log_since(box: Box, stamp: str) -> str:
    return box.run(f"journalctl -u icefloe-hwbridge --since @{stamp} --no-pager -o cat").stdout


def test_4_the_board_unplugged_and_plugged_in_again(box: Box) -> None:
    # The journal from a moment on (not "the last N seconds": on a busy machine a look into the box
    # can take longer than that, and a sliding window then misses the line).
    unplugged = box.run("date +%s.%N").stdout.strip()
    box.board("unplug")
    try:
        wait_for("hwbridge says the link is lost", lambda: "board link lost" in _hwbridge_log_since(box, unplugged),
                 60, 1)
    finally:
        plugged = box.run("date +%s.%N").stdout.strip()
        box.board("plug")
    wait_for("hwbridge says the board is back", lambda: "board link up" in _hwbridge_log_since(box, plugged), 60, 1)
    _drives_a_metre(box, "after the board was plugged in again")


def test_4_a_broken_config_fails_once_without_a_restart_loop(box: Box) -> None:
    broken = box.run("date +%s.%N").stdout.strip()
    box.run(f"cp /etc/icefloe/robots/{ROBOT}.toml /root/good.toml && "
            f"echo 'nonsense_key = 1' >> /etc/icefloe/robots/{ROBOT}.toml && systemctl restart icefloe@info")
    try:
        info = wait_for("info failed", lambda: (u := box.units()["icefloe@info.service"])["ActiveState"] == "failed"
                        and u, 60, 1)
        time.sleep(5)
        assert box.units()["icefloe@info.service"]["NRestarts"] == info["NRestarts"]
        lines = box.run(f"journalctl -u icefloe@info --since @{broken} --no-pager -o cat | grep -i nonsense_key").stdout
        assert len(lines.strip().splitlines()) == 1, lines
    finally:
        box.run(f"cp /root/good.toml /etc/icefloe/robots/{ROBOT}.toml && systemctl restart icefloe@info")


def test_5_camera_without_picamera2_says_the_apt_package_and_stays_down(box: Box) -> None:
    camera = box.units()["icefloe@camera.service"]
    assert camera["ActiveState"] == "failed" and camera["ExecMainStatus"] == "2", camera
    assert camera["NRestarts"] == "0"
    log = box.run("journalctl -b -u icefloe@camera --no-pager -o cat | grep -v '^icefloe@' | grep picamera2").stdout
    assert "python3-picamera2" in log and len(log.strip().splitlines()) == 1, log


DOCTOR = f"/opt/icefloe/venv/bin/icefloe doctor /etc/icefloe/robots/{ROBOT}.toml"
"""`icefloe doctor` as the TA runs it on the robot (as pi: the read-only guest on the bus)."""
UNIT_HINT = ("(its unit sets LimitRTPRIO and LimitMEMLOCK: deploy/up.sh installs it; journalctl -u icefloe-hwbridge "
             "says what the OS refused)")
CAMERA = ("camera: not running (no alive/camera token): sudo systemctl restart icefloe@camera; "
          "journalctl -u icefloe@camera")
"""doctor's line about the camera in the box, by design: plain Debian has no picamera2 (check 5)."""
LATE_REPLIES = re.compile(r"board: \d+ link errors in \d+ s against \d+ exchanges \(since start: 0 bad CRC, \d+ "
                          r"timeouts, 0 garbage bytes\): a loose or long cable, or something else on /dev/serial0\? "
                          r"\(journalctl -u icefloe-hwbridge\)")
"""doctor's line about a board that answered late (timeouts only: no bad CRC, no garbage): the board here
is the simulator's model, a Python process outside the box that a loaded host delays (a real board
answers in 1.4 ms). Allowed once, in exactly this shape; a corrupt frame, or no reply at all, is not."""
ODOMETRY_STOPPED = ("odometry: not running (no alive/odometry token): sudo systemctl restart icefloe@odometry; "
                    "journalctl -u icefloe@odometry")
READABLE = (f"credentials: /etc/icefloe/{ROBOT}.credentials may be read by others (-rw-r--r-- icefloe:icefloe): "
            f"sudo chmod 600 /etc/icefloe/{ROBOT}.credentials")


def _doctor(box: Box) -> list[str]:
    """Every line of doctor's that is not its summary, "OK: ..." or "not checked: ...": its problems."""
    r = box.run(DOCTOR, user="pi", timeout=120, check=False)
    assert "Traceback" not in r.stdout + r.stderr, r.stdout + r.stderr
    summary = re.compile(r"\d+ problems? on robot ")
    return [line for line in r.stdout.splitlines()
            if line and not line.startswith(("OK:", "not checked:")) and not summary.match(line)]


def _withheld(box: Box) -> list[str]:
    """doctor's lines about the real time the container withholds from hwbridge's cycle: what hwbridge's
    one line says was refused (check 2: the cycle's SCHED_FIFO 80, mlockall), with the cycle left at its
    unit's SCHED_FIFO priority, which systemd gives it."""
    said = box.run("journalctl -u icefloe-hwbridge --no-pager -o cat | grep 'real time withheld' | tail -1",
                   check=False).stdout
    unit = box.run("cat /etc/systemd/system/icefloe-hwbridge.service").stdout
    priority = re.search(r"^CPUSchedulingPriority=(\d+)$", unit, re.MULTILINE).group(1)  # type: ignore[union-attr]
    lines = []
    if "SCHED_FIFO priority 80" in said:
        lines.append(f"hwbridge: the cycle runs at SCHED_FIFO {priority}, not SCHED_FIFO 80: late cycles ahead "
                     f"{UNIT_HINT}")
    if "mlockall" in said:
        lines.append(f"hwbridge: the cycle's memory is not locked (mlockall refused): it may be paged out {UNIT_HINT}")
    return lines


def _unexplained(lines: list[str], expected: list[str]) -> list[str]:
    """doctor's lines but the ``expected`` ones (each once) and one `LATE_REPLIES` line; and a line for
    each expected one that doctor did not say."""
    rest = list(lines)
    missing = []
    for line in expected:
        if line in rest:
            rest.remove(line)
        else:
            missing.append(f"(not said: {line})")
    late = [line for line in rest if LATE_REPLIES.fullmatch(line)][:1]
    return [line for line in rest if line not in late] + missing


def _doctor_until(box: Box, expected: list[str], says: Callable[[list[str]], bool] = lambda rest: not rest,
                  timeout: float = 60) -> tuple[list[str], list[str]]:
    """doctor's lines, and those of them the box does not explain (`_unexplained`), once these are what
    ``says`` wants (by default: none), or as they are after ``timeout``. doctor is run again meanwhile:
    a service just restarted may not be back yet, and on a loaded machine (an emulated box more so)
    doctor may not hear the robot within its own budget of 7 s ("robot: stopped answering")."""
    deadline = time.monotonic() + timeout * SLOW
    while True:
        lines = _doctor(box)
        rest = _unexplained(lines, expected)
        if says(rest) or time.monotonic() > deadline:
            return lines, rest
        time.sleep(2)


UNPLUGGED = ("board: /dev/serial0 does not exist: ", "board: no reply from /dev/serial0 ", "battery: no reading ")
"""doctor's lines about an unplugged board: the device gone (its line, always), and what follows from it."""


def _only_unplugged(rest: list[str]) -> bool:
    return any(line.startswith(UNPLUGGED[0]) for line in rest) and all(line.startswith(UNPLUGGED) for line in rest)


def test_6_doctor_is_clean_and_names_each_injected_fault(box: Box) -> None:
    # Nothing filtered: every line doctor says on the healthy robot is expected, each for a reason of the
    # box's (`CAMERA`, `_withheld`, `LATE_REPLIES`): no package that differs from the lock, nothing else.
    expected = [CAMERA, *_withheld(box)]
    lines, rest = _doctor_until(box, expected)
    print(*lines, sep="\n")
    assert [line for line in lines if line.startswith("package ")] == [], "the robot's venv is not the lock's"
    assert rest == [], f"doctor says what the box does not explain: {lines}"
    # Each fault in exactly its line (the unplugged board: the device's line and what follows from it)
    box.run(f"chmod 0644 /etc/icefloe/{ROBOT}.credentials")
    try:
        assert _doctor_until(box, expected, lambda rest: rest == [READABLE])[1] == [READABLE], "readable by all"
    finally:
        box.run(f"chmod 0600 /etc/icefloe/{ROBOT}.credentials")
    box.run("systemctl stop icefloe@odometry")
    try:
        said = _doctor_until(box, expected, lambda rest: rest == [ODOMETRY_STOPPED])[1]
        assert said == [ODOMETRY_STOPPED], "a stopped service"
    finally:
        box.run("systemctl start icefloe@odometry")
    assert _doctor_until(box, expected)[1] == [], "odometry back"
    box.board("unplug")
    try:
        said = _doctor_until(box, expected, _only_unplugged)[1]
        assert _only_unplugged(said), said
    finally:
        box.board("plug")
    assert _doctor_until(box, expected)[1] == [], "the board plugged in again"


STOP_TIMER = ROOT / "tests" / "box_stop_timer.py"
"""Drives and stops from outside, timing each stop to the board (its docstring says what it prints)."""
STOPS = 5
STOP_TO_BOARD_S = 0.020
LATE_STOP_S = 0.300
"""The one stop of `STOPS` that may miss `STOP_TO_BOARD_S`, and only by this much: beside the test
suite, about one stop in 20-30 waits 30-260 ms with its cause not found (docs/deploy.md, issue 35
blocked on it among others); a stop that never comes, or two late, still fail."""
"""Issue 35: a ``cmd/stop`` reaches the board within this while a student's programs hog every CPU (the
PenguinPi firmware then applies it at its next 20 ms control step: to the board is the robot's part)."""
OVERRUNS = 0.01
"""Issue 35: the 1 kHz cycle misses at most this share of its deadlines while the CPUs are hogged."""
PERIOD_US = 1000
"""The cycle's period, µs (1 kHz)."""
WORK_US = 100
"""The cycle's own work in a period, µs (69-81 µs of CPU, docs/hwbridge.md, "CPU per period"): a
cyclictest wake-up this much before the next deadline ends in time, as the cycle's would."""
BUSY = "while :; do :; done\n"
SPIN = ("import threading\n\ndef spin():\n    while True:\n        pass\n\n"
        "for _ in range(8):\n    threading.Thread(target=spin).start()\n")
HOGS = "for i in $(seq $(nproc)); do sh ~/busy.sh & done; python3 ~/spin.py & wait"
"""A student's CPU hogs, as pi: one shell busy loop per CPU, and a Python process spinning eight threads."""


def _loop(box: Box) -> dict:
    r = subprocess.run([str(ICEFLOE), "echo", "hw/loop", "--once", "--robot", ROBOT, *_owner(box)],
                       capture_output=True, text=True, timeout=60 * SLOW, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.splitlines()[0])


def _hogs_running(box: Box) -> bool:
    """Every busy loop and the spinner's eight threads (and its main one) started."""
    # (anchored: the login shell that started them names both files too)
    r = box.run("echo $(pgrep -u pi -c -f '^sh .*busy[.]sh') "
                "$(ps -o nlwp= -p \"$(pgrep -u pi -f '^python3 .*spin[.]py')\" || echo 0) $(nproc)",
                check=False).stdout.split()
    return len(r) == 3 and r[0] == r[2] and int(r[1]) >= 9


def _cycle_at_the_pis_priority(box: Box) -> str:
    """hwbridge's cycle raised, from outside, to the SCHED_FIFO priority it raises itself to on a Pi (80),
    where the box withheld it; what it ran at before. The box cannot grant it: the unit's LimitRTPRIO=95
    needs its systemd to raise a hard limit, and this machine's root lacks CAP_SYS_RESOURCE (nspawn
    cannot pass it on); then the cycle stays at the unit's 40, with the bus side's every thread at 40
    on the same CPU, which a Pi's cycle preempts. Root here may set a priority (CAP_SYS_NICE)."""
    leader = json.loads((box.dir / "box.json").read_text())["leader"]
    pid = subprocess.run(["pgrep", "--ns", str(leader), "-f", "services[.]hwbridge[.]rt"], capture_output=True,
                         text=True).stdout.split()[0]
    was = os.sched_getparam(int(pid)).sched_priority
    if was < 80:
        os.sched_setscheduler(int(pid), os.SCHED_FIFO, os.sched_param(80))
    return f"SCHED_FIFO {was}"


def _cyclictest(cpu: int) -> subprocess.Popen[str]:
    """cyclictest as the cycle runs on a Pi: SCHED_FIFO 80 (`[hwbridge] priority`), every `PERIOD_US` on
    an absolute clock, on the cycle's CPU, memory locked; each wake-up's latency (µs) on a line."""
    return subprocess.Popen(["cyclictest", "--mlockall", "--quiet", "--priority=80", f"--affinity={cpu}",
                             f"--interval={PERIOD_US}", "--verbose"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)


def machine_overruns(latencies: list[int]) -> int:
    """The deadlines a cycle of `WORK_US` would have missed had it woken when cyclictest did, counted as
    the cycle counts its own (services/hwbridge/rt.py: a period ending after the next deadline misses
    every deadline up to its end, and those are skipped, not caught up)."""
    missed_total, skip_until = 0, 0
    for i, latency in enumerate(latencies):
        deadline = i * PERIOD_US
        if deadline < skip_until:
            continue  # the cycle skipped this deadline: cyclictest's catching up is not a wake-up of its
        late = deadline + latency + WORK_US - (deadline + PERIOD_US)
        if late > 0:
            missed = late // PERIOD_US + 1
            missed_total += missed
            skip_until = deadline + PERIOD_US * (missed + 1)
    return missed_total


def _machine(cyclictest: subprocess.Popen[str]) -> tuple[int, int, int]:
    """cyclictest stopped: `machine_overruns` of its wake-ups, their number, the largest latency (µs)."""
    cyclictest.send_signal(signal.SIGINT)
    out = cyclictest.communicate(timeout=30)[0]
    latencies = [int(m.group(1)) for m in re.finditer(r"^\s*\d+:\s*\d+:\s*(\d+)$", out, re.MULTILINE)]
    assert latencies, f"cyclictest measured nothing: {out[-500:]}"
    return machine_overruns(latencies), len(latencies), max(latencies)


def test_6_a_students_cpu_hogs_starve_neither_the_cycle_nor_a_stop(box: Box) -> None:
    """As pi, one busy loop per CPU and a process spinning eight threads; meanwhile, from outside, `STOPS`
    stops, each after a drive. Each stop reaches the board within `STOP_TO_BOARD_S` (from the router's
    delivery, where the bus itself was later than that: see below), but one that may take up to
    `LATE_STOP_S` and is printed as not met (the goal's unmet tail); the cycle's overruns
    over that window stay under `OVERRUNS`. cyclictest at the cycle's priority, on its CPU, in the same
    window, says what the machine itself allowed: where even it missed the goal (a loaded virtual
    machine), the cycle is compared with it. Measured: docs/deploy.md, "The students cannot starve the
    robot" (10 to 12 s alone, 11 to 21 s beside a stand-in for the suite)."""
    if not shutil.which("cyclictest"):
        pytest.fail("needs cyclictest, the machine's own latency at the cycle's priority (apt-get install rt-tests)")
    box.run(f"printf %s {shlex.quote(BUSY)} > ~/busy.sh && printf %s {shlex.quote(SPIN)} > ~/spin.py", user="pi")
    hogs = subprocess.Popen([str(BOX), "--dir", str(box.dir), "--name", "icefloe-test", "--arch", ARCH, "exec",
                             "--user", "pi", "--", HOGS], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    machine = None
    try:
        wait_for("the hogs running", lambda: _hogs_running(box), 30, 0.5)
        withheld = _cycle_at_the_pis_priority(box)
        load = os.getloadavg()[0]
        machine = _cyclictest((os.cpu_count() or 1) - 1)
        before = _loop(box)
        timer = subprocess.run(["nice", "-n", "-10", str(ROOT / ".venv/bin/python"), str(STOP_TIMER),
                                str(box.dir / "box.sock"), ROBOT, str(box.credentials), str(STOPS)],
                               capture_output=True, text=True, timeout=120 * SLOW, cwd=ROOT)
        after = _loop(box)
        machine_missed, machine_cycles, machine_most = _machine(machine)
    finally:
        if machine is not None and machine.poll() is None:
            machine.kill()
        box.run("pkill -KILL -u pi || true")
        hogs.kill()
        hogs.wait()
    assert timer.returncode == 0, timer.stdout + timer.stderr
    stops = [json.loads(line) for line in timer.stdout.splitlines()]
    to_board = [(s["received"] - s["put"]) * 1000 for s in stops]
    to_duty = [(s["zero_duty"] - s["put"]) * 1000 for s in stops]
    to_router = [(s["router"] - s["put"]) * 1000 for s in stops]
    cycles = after["cycles"] - before["cycles"]
    overruns = (after["overruns"] - before["overruns"]) / max(1, cycles)
    machine_share = machine_missed / machine_cycles
    print(f"the cycle at SCHED_FIFO 80 (the box's: {withheld}); "
          f"hogged (load average {load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end): "
          f"a stop to the board {', '.join(f'{ms:.1f}' for ms in to_board)} ms; to zero duty "
          f"{', '.join(f'{ms:.1f}' for ms in to_duty)} ms; through the router "
          f"{', '.join(f'{ms:.1f}' for ms in to_router)} ms; the cycle's overruns {overruns:.3%} of {cycles} cycles; "
          f"cyclictest (SCHED_FIFO 80) as the cycle would count: {machine_share:.3%} of {machine_cycles}, "
          f"its wake-ups at most {machine_most} µs late")
    assert len(stops) == STOPS, timer.stdout
    # The goal, unless the bus itself was late on that stop: the observer, a plain Zenoh session outside
    # the box, got the same put through the router later than the goal (beside a test suite, about one
    # stop in 20-30: docs/deploy.md). Then the robot's own part, from the router's delivery to the
    # board, is held to the goal instead, and the line says so: the same-run reference, as cyclictest
    # is for the cycle below.
    bound = STOP_TO_BOARD_S * 1000
    late_bus = [(board, router) for board, router in zip(to_board, to_router, strict=True)
                if board > bound and router > bound]
    if late_bus:
        print(f"the bus itself was late on {len(late_bus)} of {STOPS} stops (through the router "
              f"{', '.join(f'{r:.1f}' for _, r in late_bus)} ms): held to {bound:.0f} ms from the router's delivery")
    robots_part = [board if router <= bound else board - router
                   for board, router in zip(to_board, to_router, strict=True)]
    late = [ms for ms in robots_part if ms > bound]
    if late:  # the goal is not met on these: say so, every run, and hold them to LATE_STOP_S
        print(f"NOT MET: {len(late)} of {STOPS} stops over {bound:.0f} ms in the robot "
              f"({', '.join(f'{ms:.1f}' for ms in late)} ms; docs/deploy.md)")
    assert len(late) <= 1 and max(robots_part) <= LATE_STOP_S * 1000, (to_board, to_router)
    # The goal, unless this machine itself missed it at the cycle's priority in the same window (beside
    # a test suite, a virtual machine's CPUs stall for milliseconds): then the cycle may miss what the
    # machine missed, and no more than the goal's share on top (its own part), and the line says so.
    allowed = OVERRUNS if machine_share <= OVERRUNS else machine_share + OVERRUNS
    if allowed > OVERRUNS:
        print(f"the machine itself missed {machine_share:.3%} at SCHED_FIFO 80: the cycle is held to "
              f"{allowed:.3%}, the machine's and the goal's {OVERRUNS:.0%} on top")
    assert overruns <= allowed, f"the cycle missed {overruns:.3%}, the machine {machine_share:.3%}"


KERNEL_LINE = re.compile(r"^\[\s*(\d+\.\d+)\] (.*)$", re.MULTILINE)
"""A line of ``dmesg``: its time stamp (s since boot) and its text."""
HOG = "python3 -c 'chunks = []\nwhile True: chunks.append(b\"x\" * (16 << 20))'; echo \"hog exited $?\""
"""A student's program allocating until something gives (16 MiB at a time, every page written)."""


def test_6_a_students_memory_hog_is_what_the_oom_killer_takes(box: Box) -> None:
    before = box.units(FORKSERVER)

    def kernel_log() -> list[tuple[float, str]]:  # the kernel's log is this machine's: the box has none of its own
        log = subprocess.run(["dmesg"], capture_output=True, text=True).stdout
        return [(float(stamp), line) for stamp, line in KERNEL_LINE.findall(log)]

    # By the kernel's time stamps, not by counting lines: each kill writes about a hundred lines, and
    # the ring buffer drops the oldest ones (a CI run found no new line by count after a wrap).
    since = max((stamp for stamp, _ in kernel_log()), default=0.0)
    said = box.run(HOG, user="pi", timeout=300).stdout
    assert "hog exited 137" in said, said  # SIGKILL: the OOM killer's
    now = [line for stamp, line in kernel_log() if stamp > since and "Killed process" in line]
    print(*now, said.strip(), sep="\n")
    assert len(now) == 1 and "(python3)" in now[0], now
    after = box.units(FORKSERVER)
    for unit in [*UNITS, FORKSERVER]:
        assert (after[unit]["MainPID"], after[unit]["NRestarts"]) == (before[unit]["MainPID"],
                                                                      before[unit]["NRestarts"]), unit
    _drives_a_metre(box, "after a student's memory hog")


def test_7_down_removes_everything_and_installing_again_works(box: Box) -> None:
    added = json.loads(box.run("cat /opt/icefloe/install.json").stdout)["added"]
    groups = [entry[1] for entry in added if entry[0] == "group"]  # those the install made (spi, gpio)
    box.run(f"cd ~/icefloe && ./deploy/down.sh {ROBOT}", user="pi", timeout=300)
    # No unit (file, link or loaded), rule, tmpfiles entry, folder, user, group or process left
    # (the enable links are in *.wants/; an emulated box has drop-ins of its own, icefloe-box-qemu.conf)
    left = box.run("ls -d /etc/systemd/system/icefloe* /etc/systemd/system/*.wants/icefloe* "
                   "/etc/udev/rules.d/99-icefloe.rules /etc/tmpfiles.d/icefloe.conf /opt/icefloe /var/lib/icefloe "
                   "/etc/icefloe/robots /run/icefloe "
                   f"2>/dev/null; getent passwd icefloe; getent group icefloe {' '.join(groups)}; "
                   "systemctl list-units --all 'icefloe*' --no-legend --plain; "
                   "systemctl list-unit-files 'icefloe*' --no-legend; pgrep -a -f /opt/icefloe", check=False)
    assert left.stdout.strip() == "", left.stdout
    # The credentials file stays (down.sh keeps it: its owners hold the same password; --purge removes it)
    assert box.run(f"stat -c '%U %a' /etc/icefloe/{ROBOT}.credentials").stdout.split() == ["root", "600"]
    box.sh("install", timeout=1200)
    wait_for("every unit active again", lambda: all(box.units()[u]["ActiveState"] == "active" for u in UNITS), 120, 2)


def test_box_json_records_the_commit(box: Box) -> None:
    info = json.loads((box.dir / "box.json").read_text())
    head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=ROOT).stdout.strip()
    assert info["rev"] == head
