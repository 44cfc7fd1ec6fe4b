"""`icefloe doctor`: the health check a TA runs after an install, or when a student says "it
doesn't move". One line per problem, each naming its fix; a short OK summary otherwise; exit
status 1 on any problem. It never takes longer than about ten seconds, even when the robot is
dead (docs/deploy.md, "Checking a robot").

Over the bus (on the robot, or from a laptop with ``--connect``/``--credentials``), read only
(as the read-only ``guest`` on a robot with access control, unless given credentials):

* the router and every service of the config alive (their liveliness tokens);
* the board link: ``hw/loop``'s exchange rate and error counters, over two reports;
* real time: the ``SCHED_FIFO`` priority and memory lock the cycle was granted (a real board only);
* the camera delivering frames (``camera/landmarks``, one per frame), the battery (``power/battery``);
* the clock: not 1970, and the robot's stamps against this machine's clock.

On this machine (the robot, or the laptop running doctor): every installed package at the lock's
version (`icefloe.lock`: one line each, naming the package, the lock's version and the installed one).

On the robot only (no ``--connect``): the devices the config names (serial port, SPI, I2C, GPIO,
camera) present and usable by the services' user (``icefloe`` where it exists), and the
credentials file private to that user. From a laptop, or for a simulated board, the local
checks that do not apply are skipped with a line saying so.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import pwd
import stat
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec

from .. import config as config_mod
from .. import lock
from ..config import RobotConfig
from ..deploy import USER as SERVICES_USER
from ..errors import ConfigError, IcefloeError, NotReachable
from ..runtime import listening, run_async
from ..schemas import keys
from ..schemas import messages as m
from .bus import robot_of
from .common import Done, add_bus_arguments, bus_config, check_robot, cli_node, config_names, drain

BUDGET_S = 7.0
"""The bus checks give up after this long (Python's start and the local checks come on top)."""
LISTEN_S = 2.5
"""How long to listen for ``hw/loop`` (1 Hz: two reports), the battery and the camera."""
SANE_NS = 1_704_067_200 * 10**9
"""2024-01-01: a clock before this has not been set (a Pi has no clock battery: 1970 until NTP)."""
SKEW_S = 2.0
"""The robot's stamps may differ from this machine's clock by this much (and the bus's delay)."""
WAIT_ROUND_S = 1.0
"""With ``--wait``: the pause between two rounds of checks."""
ERROR_SHARE = 0.01
"""Link errors above this share of the exchanges are a problem (a few stray ones are not)."""


@dataclass
class Report:
    """What the checks found: problems (one line each, naming the fix), facts for the OK summary,
    and checks skipped here (with why)."""

    problems: list[str] = field(default_factory=list)
    facts: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    stage: str = "starting"
    """What the bus checks were doing: named when the robot stops answering."""


# ---------------------------------------------------------------------- where and as whom


def services_user() -> pwd.struct_passwd:
    """The user the services run as: ``icefloe`` on an installed robot, else whoever runs this."""
    try:
        return pwd.getpwnam(SERVICES_USER)
    except KeyError:
        return pwd.getpwuid(os.getuid())


def installed(config: RobotConfig) -> bool:
    """Does the robot run under systemd (a real board: deploy/up.sh installs it), or under
    `icefloe up` (the simulated one)? It decides where a fix looks for a service's log."""
    return config.board.backend == "hardware"


def unit(service: str) -> str:
    """The systemd unit of a service on an installed robot (deploy/systemd)."""
    return f"icefloe-{service}" if service in ("router", "hwbridge") else f"icefloe@{service}"


def logs(config: RobotConfig, service: str) -> str:
    """Where a service's log is: its systemd unit's journal, or `icefloe up`'s output."""
    return f"journalctl -u {unit(service)}" if installed(config) else "the output of `icefloe up` says why"


def doctor_config(args: argparse.Namespace) -> RobotConfig:
    """The config as other bus verbs read it. On a robot, the credentials file belongs to the
    services' user and the TA may not read it: then doctor reads the robot as the guest does."""
    args.config = args.config or args.robot_config
    try:
        return bus_config(args)
    except ConfigError as exc:
        if not isinstance(exc.__context__, PermissionError):
            raise
    cfg = config_mod.load(args.config, credentials=False)
    if args.connect:
        cfg = msgspec.structs.replace(cfg, zenoh=msgspec.structs.replace(cfg.zenoh, connect=args.connect))
    return cfg


# ---------------------------------------------------------------------- local checks


DEVICE_HINTS = {
    "serial": "is the serial port on (enable_uart=1 in /boot/firmware/config.txt, no serial console: "
              "deploy/up.sh sets both) and the Pi rebooted since?",
    "SPI": "is SPI on (dtparam=spi=on in /boot/firmware/config.txt: deploy/up.sh sets it) and the Pi "
           "rebooted since?",
    "I2C": "is I2C on (dtparam=i2c_arm=on in /boot/firmware/config.txt) and the Pi rebooted since?",
    "GPIO": "is this a Raspberry Pi? (power.gpio = \"none\" runs without the shutdown lines)",
    "camera": "is the camera plugged in?",
}


def devices(config: RobotConfig) -> list[tuple[str, str, str]]:
    """(area, device path, kind) of every device the config's services open."""
    out = []
    b = config.board
    out.append(("board", b.serial_port, "serial") if b.kind == "penguinpi" else ("board", b.spi_device, "SPI"))
    if "oled" in config.services and config.display.kind == "ssd1306":
        out.append(("oled", f"/dev/i2c-{config.display.i2c_port}", "I2C"))
    if "power" in config.services and config.power.gpio == "gpiod":
        out.append(("power", config.power.gpio_chip, "GPIO"))
    source = config.camera.source
    if "camera" in config.services and source.startswith("v4l2:"):
        where = source.removeprefix("v4l2:")
        out.append(("camera", f"/dev/video{where}" if where.isdigit() else where, "camera"))
    return out


def may_use(st: os.stat_result, user: pwd.struct_passwd) -> bool:
    """May ``user`` read and write a file of this mode and owner (the kernel's test: owner's bits,
    else the group's if the user is in it, else everyone's)?"""
    if user.pw_uid == 0:
        return True
    if st.st_uid == user.pw_uid:
        bits = st.st_mode >> 6
    elif st.st_gid in os.getgrouplist(user.pw_name, user.pw_gid):
        bits = st.st_mode >> 3
    else:
        bits = st.st_mode
    return bits & 0o6 == 0o6


def owner_text(st: os.stat_result) -> str:
    """``crw-rw---- root:dialout``, as ``ls -l`` shows it."""
    import grp

    def name(get: Any, ident: int) -> str:
        try:
            return get(ident)[0]
        except KeyError:
            return str(ident)

    return f"{stat.filemode(st.st_mode)} {name(pwd.getpwuid, st.st_uid)}:{name(grp.getgrgid, st.st_gid)}"


def check_devices(config: RobotConfig, user: pwd.struct_passwd, report: Report) -> None:
    import grp

    for area, path, kind in devices(config):
        try:
            st = os.stat(path)
        except FileNotFoundError:
            report.problems.append(f"{area}: {path} does not exist: {DEVICE_HINTS[kind]}")
            continue
        except OSError as exc:
            report.problems.append(f"{area}: cannot look at {path}: {exc.strerror}")
            continue
        if not stat.S_ISCHR(st.st_mode):
            report.problems.append(f"{area}: {path} is not a device ({owner_text(st)}): a file left in its "
                                   f"place? remove it and reboot")
        elif not may_use(st, user):
            group = grp.getgrgid(st.st_gid).gr_name if st.st_mode & 0o060 == 0o060 else ""
            fix = (f"sudo usermod -aG {group} {user.pw_name}, then sudo systemctl restart icefloe.target"
                   if group and group != "root" else
                   "its udev rule is missing (deploy/up.sh installs it; then sudo udevadm trigger)")
            report.problems.append(f"{area}: {path} is not readable and writable by {user.pw_name} "
                                   f"({owner_text(st)}): {fix}")
        else:
            report.facts.append(f"{path} ok")


def check_credentials(config: RobotConfig, user: pwd.struct_passwd, report: Report) -> None:
    """The robot's credentials file: there, and private to the services' user."""
    path = Path(config.zenoh.credentials).expanduser()
    remake = f"./deploy/up.sh {config.name} makes it" if installed(config) else \
        f"icefloe credentials {config.source} makes it"
    try:
        st = os.stat(path)
    except FileNotFoundError:
        report.problems.append(f"credentials: {path} is missing, so nobody may drive the robot: {remake}")
        return
    except PermissionError:
        report.skipped.append(f"credentials: {path} cannot be looked at by {pwd.getpwuid(os.getuid()).pw_name} "
                              "(sudo icefloe doctor checks it)")
        return
    if st.st_mode & 0o077:
        report.problems.append(f"credentials: {path} may be read by others ({owner_text(st)}): "
                               f"sudo chmod 600 {path}")
    if st.st_uid != user.pw_uid:
        report.problems.append(f"credentials: {path} belongs to {owner_text(st).split()[1]}, not to "
                               f"{user.pw_name}, who runs the services: sudo chown {user.pw_name}: {path}")


def check_own_copy(path: str, report: Report) -> None:
    """A laptop's copy of a robot's credentials (``--credentials``): private to its user."""
    p = Path(path).expanduser()
    st = os.stat(p)  # bus_config has read it already
    if st.st_mode & 0o077:
        report.problems.append(f"credentials: your copy {p} may be read by others ({owner_text(st)}): chmod 600 {p}")


def check_clock(report: Report) -> None:
    now = time.time_ns()
    if now < SANE_NS:
        report.problems.append(f"clock: this machine's clock says {time.strftime('%Y-%m-%d', time.gmtime(now / 1e9))}: "
                               "it was never set (no network time yet?): timedatectl")


def check_lock(report: Report) -> None:
    """Every installed package the lock knows at the lock's version; icefloe's own dependencies there."""
    try:
        locked = lock.runtime_pins()
        drifted = lock.drift(locked, lock.installed(), required=lock.base_requirements())
    except lock.LockError as exc:
        report.problems.append(f"lock: {exc}")
        return
    again = f"{sys.executable} -m pip install --require-hashes -r {lock.folder()}/<extra>.txt (deploy/up.sh does)"
    for d in drifted:
        report.problems.append(f"package {d}: the lock's versions are what icefloe is tested with: {again}")
    if not drifted:
        report.facts.append(f"{len(locked)} packages as locked")


def local_checks(args: argparse.Namespace, config: RobotConfig, remote: bool, report: Report) -> None:
    check_clock(report)
    if args.credentials:
        check_own_copy(args.credentials, report)
    if remote:
        report.skipped.append("devices and credentials file: from a laptop (run icefloe doctor on the robot)")
        return
    user = services_user()
    if config.board.backend == "hardware":
        check_devices(config, user, report)
    else:
        report.skipped.append("devices: a simulated board")
    if config.zenoh.access_control and config.zenoh.credentials:
        check_credentials(config, user, report)


# ---------------------------------------------------------------------- over the bus


@dataclass
class Heard:
    """What arrived while listening, each with this machine's clock at arrival (ns)."""

    loops: list[tuple[m.LoopStats, int]] = field(default_factory=list)
    battery: tuple[m.Battery, int] | None = None
    frames: int = 0


async def listen(node: Any, robot: str, want: set[str]) -> Heard:
    """Listen to hw/loop (two reports), power/battery and camera/landmarks (one each), at most `LISTEN_S`."""
    heard = Heard()

    def loop(msg: m.LoopStats) -> None:
        heard.loops.append((msg, time.time_ns()))
        if len(heard.loops) >= 2:
            raise Done

    def battery(msg: m.Battery) -> None:
        heard.battery = (msg, time.time_ns())
        raise Done

    def frame(_: m.Landmarks) -> None:
        heard.frames += 1
        raise Done

    listeners = [(keys.LOOP, loop, "hwbridge"), (keys.BATTERY, battery, "power"),
                 (keys.LANDMARKS, frame, "camera")]
    await asyncio.gather(*(drain(node.subscribe(topic, robot=robot, latest=False), LISTEN_S, handle)
                           for topic, handle, service in listeners if service in want))
    return heard


async def bus_checks(config: RobotConfig, robot: str, remote: bool, report: Report) -> None:
    endpoints = ", ".join(config.zenoh.connect)
    report.stage = f"opening a session with the router at {endpoints}"
    try:
        node = await cli_node(config).__aenter__()
    except NotReachable as exc:
        report.problems.append(f"router: {exc}")
        return
    try:
        report.stage = "asking which services are alive, and listening"
        expected = ["router", *config.services]
        tokens, heard = await asyncio.gather(node.alive("*"), listen(node, robot, set(expected)))
    finally:
        node.close()
    report.stage = "done"
    alive = {service for r, service in filter(None, map(keys.alive_of, tokens)) if r == robot}
    if not alive:
        start = "sudo systemctl start icefloe.target" if installed(config) else "icefloe up"
        report.problems.append(f"robot: {check_robot(tokens, robot)}: is it up? ({start})")
        return
    missing = [s for s in expected if s not in alive]
    for service in missing:
        fix = f"sudo systemctl restart {unit(service)}; " if installed(config) else ""
        report.problems.append(f"{service}: not running (no alive/{service} token): {fix}{logs(config, service)}")
    report.facts.append(f"{len(expected) - len(missing)} of {len(expected)} alive (the router and "
                        f"{', '.join(config.services)})")
    if "hwbridge" in alive:
        check_board(config, heard, report)
        check_realtime(config, heard, report)
    if "camera" in alive:
        check_camera(config, heard, report)
    if "power" in alive:
        check_battery(config, heard, report)
    check_stamps(heard, remote, report)


def check_board(config: RobotConfig, heard: Heard, report: Report) -> None:
    b = config.board
    device = b.serial_port if b.kind == "penguinpi" else (b.spi_device if b.backend == "hardware" else b.sim_socket)
    if not heard.loops:
        report.problems.append(f"hwbridge: alive, but no hw/loop report in {LISTEN_S:g} s: its cycle is stuck "
                               f"or starved ({logs(config, 'hwbridge')})")
        return
    first, last = heard.loops[0][0], heard.loops[-1][0]
    if last.link_rate <= 0:
        cause = ("is the board powered and its cable in?" if b.backend == "hardware" else
                 "is the simulator (service sim) running and not stopped?")
        report.problems.append(f"board: no reply from {device} (0 exchanges in the last second, "
                               f"{last.timeouts} timeouts since start): {cause} ({logs(config, 'hwbridge')})")
        return
    errors = last.link_errors - first.link_errors
    if b.backend != "hardware":  # the simulator late on a busy machine is no fault of a cable: corruption only
        errors = sum(getattr(last, k) - getattr(first, k) for k in ("crc_errors", "garbage_bytes", "unmatched"))
    seconds = max((last.stamp - first.stamp) / 1e9, 1e-3)
    exchanges = last.link_rate * seconds
    if len(heard.loops) >= 2 and errors > max(2.0, ERROR_SHARE * exchanges):
        report.problems.append(
            f"board: {errors} link errors in {seconds:.0f} s against {exchanges:.0f} exchanges (since start: "
            f"{last.crc_errors} bad CRC, {last.timeouts} timeouts, {last.garbage_bytes} garbage bytes): a loose or "
            f"long cable, or something else on {device}? ({logs(config, 'hwbridge')})")
    if len(heard.loops) >= 2 and last.board_errors > first.board_errors:
        report.problems.append(f"board: it reported {last.board_errors - first.board_errors} errors of its own "
                               f"in {seconds:.0f} s ({logs(config, 'hwbridge')} shows them)")
    report.facts.append(f"board {last.board} {last.link_rate:.0f} exchanges/s")


def check_realtime(config: RobotConfig, heard: Heard, report: Report) -> None:
    if config.board.backend != "hardware":
        report.skipped.append("real time of the cycle: a simulated board")
        return
    if not heard.loops:
        return  # check_board said so
    last = heard.loops[-1][0]
    want = config.hwbridge.priority
    unit = "(its unit sets LimitRTPRIO and LimitMEMLOCK: deploy/up.sh installs it; journalctl -u icefloe-hwbridge " \
           "says what the OS refused)"
    if last.realtime_priority != want:
        got = f"SCHED_FIFO {last.realtime_priority}" if last.realtime_priority else "normal scheduling"
        report.problems.append(f"hwbridge: the cycle runs at {got}, not SCHED_FIFO {want}: late cycles ahead {unit}")
    if not last.memory_locked:
        report.problems.append(f"hwbridge: the cycle's memory is not locked (mlockall refused): it may be paged "
                               f"out {unit}")
    if last.realtime_priority == want and last.memory_locked:
        report.facts.append(f"SCHED_FIFO {want}, memory locked")


def check_camera(config: RobotConfig, heard: Heard, report: Report) -> None:
    if heard.frames:
        report.facts.append("camera delivering")
        return
    source = config.camera.source
    hint = {"picamera2": "is the camera's ribbon cable in? (rpicam-hello --list-cameras lists it)",
            "sim": "is the simulator's camera on ([sim] camera = true)?"}.get(source, "is the camera plugged in?")
    report.problems.append(f"camera: no frame in {LISTEN_S:g} s from {source}: {hint} ({logs(config, 'camera')})")


def check_battery(config: RobotConfig, heard: Heard, report: Report) -> None:
    if heard.battery is None:
        report.problems.append(f"battery: no reading on power/battery in {LISTEN_S:g} s: does hwbridge reach the "
                               f"board? ({logs(config, 'power')})")
        return
    b = heard.battery[0]
    if b.state == "critical":
        report.problems.append(f"battery: {b.voltage:.2f} V, critical: charge it now, the robot powers itself off")
    elif b.state == "low":
        report.problems.append(f"battery: {b.voltage:.2f} V, low: charge it soon")
    else:
        report.facts.append(f"battery {b.voltage:.2f} V")


def check_stamps(heard: Heard, remote: bool, report: Report) -> None:
    """The robot's stamps: set (not 1970), and near this machine's clock (from a laptop)."""
    if heard.loops:
        stamp, at = heard.loops[-1][0].stamp, heard.loops[-1][1]
    elif heard.battery:
        stamp, at = heard.battery[0].stamp, heard.battery[1]
    else:
        return
    if stamp < SANE_NS:
        day = time.strftime("%Y-%m-%d", time.gmtime(stamp / 1e9))
        report.problems.append(f"clock: the robot's clock says {day}: it was never set (no network time? a Pi has "
                               "no clock battery): timedatectl on the robot")
    elif remote and abs(at - stamp) > SKEW_S * 1e9:
        off = (at - stamp) / 1e9
        report.problems.append(f"clock: the robot's clock is {abs(off):.1f} s {'behind' if off > 0 else 'ahead of'} "
                               "this machine's: stamps and recordings will disagree (timedatectl, on both)")
    else:
        report.facts.append("clock ok")


# ---------------------------------------------------------------------- the verb


def bounded(config: RobotConfig, robot: str, remote: bool, report: Report) -> bool:
    """Run the bus checks in a thread of their own; False if they did not end within `BUDGET_S`
    (a robot that accepts a connection and then says nothing): that thread is left behind."""
    done = threading.Event()
    failed: list[BaseException] = []

    def target() -> None:
        try:
            run_async(bus_checks(config, robot, remote, report))
        except BaseException as exc:  # handed to the main thread, which raises it
            failed.append(exc)
        finally:
            done.set()

    threading.Thread(target=target, name="doctor", daemon=True).start()
    if not done.wait(BUDGET_S):
        return False
    if failed:
        raise failed[0]
    return True


def unanswered(config: RobotConfig, stage: str) -> str:
    """The one line for a robot that did not answer in time."""
    if stage.startswith("opening"):
        reached = [e for e in config.zenoh.connect if listening(e, 0.5)]
        why = (f"{', '.join(reached)} accepts connections but did not answer: a router that hangs, or not a "
               f"Zenoh router? ({logs(config, 'router')})" if reached else
               "nothing answers there: is the robot on, and on this network?")
        return f"router: no session within {BUDGET_S:g} s: {why}"
    return f"robot: stopped answering within {BUDGET_S:g} s while {stage}: is it overloaded or hanging?"


def doctor(args: argparse.Namespace) -> int:
    config = doctor_config(args)
    robot = robot_of(args, config)
    if not keys.is_concrete(robot) or "/" in robot:
        raise IcefloeError(f"--robot {robot!r}: doctor checks one robot, by its name (`icefloe status` lists them)")
    remote = bool(args.connect or args.credentials)
    give_up = time.monotonic() + args.wait
    while True:
        report = Report()
        local_checks(args, config, remote, report)
        answered = bounded(config, robot, remote, report)
        check_lock(report)   # this machine's packages: the robot's own, or the laptop's
        if not report.problems or not answered or time.monotonic() + WAIT_ROUND_S > give_up:
            break
        time.sleep(WAIT_ROUND_S)  # --wait: a robot still starting (after a reboot, an install)
    if not answered:
        report.problems.append(unanswered(config, report.stage))
        status = show(report, robot)
        sys.stdout.flush()
        # The checks' thread is stuck in a Zenoh call that cannot be cancelled, and Python would wait
        # for it at exit (Zenoh gives up opening a session after 10 s, then tries again as the guest).
        os._exit(status)
    return show(report, robot)


def show(report: Report, robot: str) -> int:
    """Print the report; the exit status: 1 if there is any problem."""
    for line in report.problems:
        print(line, flush=True)
    for line in report.skipped:
        print(f"not checked: {line}")
    if report.problems:
        print(f"{len(report.problems)} problem{'s' if len(report.problems) > 1 else ''} on robot {robot}")
        return 1
    print(f"OK: robot {robot}: {', '.join(report.facts)}")
    return 0


def register(verbs: argparse._SubParsersAction) -> None:
    help_ = "check a robot's health: board link, services, devices, real time, camera, battery, credentials, clock"
    p = verbs.add_parser("doctor", help=help_, description=help_ + ". One line per problem, naming its fix; "
                         "exit status 1 on any; at most about 10 s, even when the robot is dead.")
    add_bus_arguments(p)
    p.add_argument("--wait", type=float, default=0.0, metavar="S",
                   help="check again until the robot is healthy or S seconds have passed (a robot still "
                        "starting, after a reboot); the report is the last round's (default 0: once)")
    action = p.add_argument("robot_config", nargs="?", metavar="ROBOT",
                            help="robot config: a name (penguin1, sim) or a path to a .toml file (as --config)")
    action.completer = config_names  # type: ignore[attr-defined]
    p.set_defaults(run=doctor)
