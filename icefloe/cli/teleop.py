"""The `teleop` verb: drive a robot from the keyboard, like ROS's ``teleop_twist_keyboard``.

    w / Up      forward           q  e    forward, turning left / right
    s / Down    backward          z  c    backward, turning (as teleop_twist_keyboard's m and .)
    a / Left    turn left
    d / Right   turn right        + -     faster / slower (speed and turn rate, x1.25)
    space / x   stop now          Ctrl-C, Esc or Ctrl-D: stop and quit
    !           the lab's emergency stop (the TA's credentials): hold every robot on the bus stopped
    m           the car mode (below): keys steer, not spin

Hold a key (or tap it again and again): the robot keeps the last motion while keys keep coming,
sent as ``cmd/twist`` ten times a second, and stops (``cmd/stop``) when none came for
``--hold`` seconds (0.8 s: longer than a terminal's auto-repeat delay, so holding a key drives
smoothly). It stops at once on space, when the terminal loses focus (terminals that report
focus: xterm, GNOME Terminal, iTerm2, kitty, Windows Terminal, tmux with ``focus-events on``),
and when teleop ends for any reason (a key, Ctrl-C, SIGTERM, the terminal closing).

``!`` is the lab's TA's (docs/lab.md): it asks every robot whose hwbridge is alive on the bus to
stop and hold (``lab/stop``, as ``icefloe lab stop --hold``) and prints which confirmed; only the
TA's credentials may, others hear no answer. ``icefloe lab release`` ends the holds.

``m`` (or ``--car`` from the start) switches to the car mode: the robot is driven as the virtual
car of its ``[car]`` config (``cmd/car``, docs/motion-models.md), whose keys steer, not spin:

    w / Up      faster (0.05 m/s a press; from backward through 0 to forward)
    s / Down    slower (0 is a stop; below it, backward)
    a / Left    steer left (a sixth of car.max_steer a press)
    d / Right   steer right
    space / x   stop now (the steering stays where it is, as a car's wheel does)
    m           back to the unicycle keys (and stop)

The car keeps its speed and steering while no key comes, as a car's cruise control does (there
is no key to hold), sent as ``cmd/car`` ten times a second while its speed is not 0; it stops at
once on space, at speed 0, when the terminal loses focus and when teleop ends. A steering key at
speed 0 sends nothing (a stopped robot stays stopped): the car steers to that angle when it next
drives. The status line shows what hwbridge applies (``car/state``): the steering after its rate
limit, the speed after the wheels' limit.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import os
import signal
import sys
import termios
import time
import tty
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import msgspec

from .. import labstop
from ..config import RobotConfig
from ..errors import IcefloeError
from ..motion.car import turn_radius
from ..runtime import Node, Publisher, Subscription
from ..schemas import keys
from ..schemas import messages as m
from .bus import on_bus
from .common import add_bus_arguments, check_robot, warn

MOTIONS: dict[bytes, tuple[int, int, str]] = {
    b"w": (1, 0, "forward"), b"\x1b[A": (1, 0, "forward"),
    b"s": (-1, 0, "backward"), b"\x1b[B": (-1, 0, "backward"),
    b"a": (0, 1, "turn left"), b"\x1b[D": (0, 1, "turn left"),
    b"d": (0, -1, "turn right"), b"\x1b[C": (0, -1, "turn right"),
    b"q": (1, 1, "forward left"), b"e": (1, -1, "forward right"),
    b"z": (-1, -1, "backward left"), b"c": (-1, 1, "backward right"),
}
"""Key -> (direction of v, direction of w, what it does); arrows as the terminal sends them."""
STOP_KEYS = (b" ", b"x")
LAB_STOP_KEY = b"!"
QUIT_KEYS = (b"\x03", b"\x04", b"\x1b")
FASTER, SLOWER = (b"+", b"="), (b"-", b"_")
MODE_KEY = b"m"
CAR_KEYS: dict[bytes, tuple[int, int]] = {
    b"w": (1, 0), b"\x1b[A": (1, 0), b"s": (-1, 0), b"\x1b[B": (-1, 0),
    b"a": (0, 1), b"\x1b[D": (0, 1), b"d": (0, -1), b"\x1b[C": (0, -1),
}
"""Car mode: key -> (speed steps, steering steps) it adds."""
CAR_SPEED_STEP = 0.05
"""m/s a speed key adds in car mode."""
CAR_STEER_STEPS = 6
"""Steering keys from straight to full lock (car.max_steer) in car mode."""
FOCUS_IN, FOCUS_OUT = b"\x1b[I", b"\x1b[O"
FOCUS_REPORTING = ("\x1b[?1004h", "\x1b[?1004l")
"""Ask the terminal to report focus changes (xterm's mode 1004), and stop asking."""
STEP = 1.25


@dataclass
class Drive:
    """What the keys ask for: pure logic, tested without a terminal."""

    speed: float
    """m/s for a forward key."""
    turn: float
    """rad/s for a turn key."""
    max_speed: float
    max_turn: float
    hold: float
    v: float = 0.0
    w: float = 0.0
    doing: str = "stopped"
    last_key: float = 0.0

    topic: ClassVar[keys.Topic] = keys.TWIST

    @property
    def moving(self) -> bool:
        return self.v != 0.0 or self.w != 0.0

    def key(self, key: bytes, now: float) -> str:
        """Apply one key; returns "move", "stop", "quit", "lab stop", "mode" or "" (nothing to send)."""
        if (common := common_key(self, key)) is not None:
            return common
        if key in FASTER or key in SLOWER:
            factor = STEP if key in FASTER else 1 / STEP
            self.speed = min(self.speed * factor, self.max_speed)
            self.turn = min(self.turn * factor, self.max_turn)
            if self.moving:  # the motion under way changes speed too
                self.v, self.w = (self.speed if self.v > 0 else -self.speed if self.v < 0 else 0.0,
                                  self.turn if self.w > 0 else -self.turn if self.w < 0 else 0.0)
                self.last_key = now
                return "move"
            return ""
        if key in MOTIONS:
            dv, dw, self.doing = MOTIONS[key]
            self.v, self.w = dv * self.speed, dw * self.turn
            self.last_key = now
            return "move"
        return ""

    def expired(self, now: float) -> bool:
        """No key for `hold` s while moving: the deadman. Stops the motion and says so."""
        if self.moving and now - self.last_key > self.hold:
            self.stop(f"stopped: no key for {self.hold:g} s")
            return True
        return False

    def stop(self, why: str) -> None:
        self.v = self.w = 0.0
        self.doing = why

    def line(self) -> str:
        return (f"v {self.v:+.2f} m/s  w {self.w:+.2f} rad/s  {self.doing:<34} "
                f"(speed {self.speed:.2f} m/s, turn {self.turn:.2f} rad/s)")

    def message(self, command: Callable[..., m.Command]) -> m.Command:
        """What to send now (``command`` is `Node.command`: it numbers it)."""
        return command(m.Twist, v=self.v, w=self.w)


@dataclass
class CarKeys:
    """What the keys ask of the virtual car (``cmd/car``): pure logic, tested without a terminal.
    Speed and steering go in whole steps, so the keys come back to exactly 0 and to straight."""

    max_speed: float
    """m/s: the robot's ``max_wheel_speed`` (hwbridge slows a turn that needs more of a wheel)."""
    max_steer: float
    """rad: the car's ``max_steer``; the steering's steps reach exactly this."""
    wheelbase: float
    """m: the car's, for the turn's radius on the status line."""
    speed_step: float = CAR_SPEED_STEP
    steer_steps: int = CAR_STEER_STEPS
    gear: int = 0
    """The speed in steps: ``v = gear * speed_step``."""
    lock: int = 0
    """The steering in steps: ``steer = lock / steer_steps * max_steer``."""
    doing: str = "stopped"
    applied: m.CarState | None = None
    """The latest ``car/state``: what hwbridge applies (the steering after its rate limit)."""
    topic: ClassVar[keys.Topic] = keys.CAR

    @property
    def v(self) -> float:
        return self.gear * self.speed_step

    @property
    def steer(self) -> float:
        return self.lock / self.steer_steps * self.max_steer

    @property
    def moving(self) -> bool:
        return self.gear != 0

    def key(self, key: bytes, now: float) -> str:
        """Apply one key; returns "move" (send now, and keep sending while the speed is not 0), "stop",
        "quit", "lab stop", "mode" or "" (nothing to send: a steering key at speed 0 sets the angle
        the car steers to when it drives; a stopped robot gets no command that would end its stop)."""
        if (common := common_key(self, key)) is not None:
            return common
        if key not in CAR_KEYS:
            return ""
        dgear, dlock = CAR_KEYS[key]
        top = math.floor(self.max_speed / self.speed_step + 1e-9)
        self.gear = max(-top, min(top, self.gear + dgear))
        self.lock = max(-self.steer_steps, min(self.steer_steps, self.lock + dlock))
        if dgear and not self.moving:
            self.stop("stopped (speed 0)")
            return "stop"
        if not self.moving:
            self.doing = "stopped (steers when it drives)"
            return ""
        self.doing = "forward" if self.gear > 0 else "backward"
        return "move"

    def expired(self, now: float) -> bool:
        """No deadman of keys: the car keeps its speed (a car's cruise control), see the module's doc."""
        return False

    def stop(self, why: str) -> None:
        """Speed 0; the steering stays where it is (hwbridge keeps it too)."""
        self.gear = 0
        self.doing = why

    def line(self) -> str:
        turn = "straight" if self.lock == 0 else (
            f"R {turn_radius(self.steer, self.wheelbase):.2f} m {'left' if self.lock > 0 else 'right'}")
        now = ""
        if (a := self.applied) is not None:
            now = f"| now: steer {a.steer:+.2f} rad, v {a.v:+.2f} m/s{'' if a.driving else ', not driving'}"
        return f"car: v {self.v:+.2f} m/s  steer {self.steer:+.2f} rad ({turn})  {self.doing:<22} {now}"

    def message(self, command: Callable[..., m.Command]) -> m.Command:
        """What to send now (``command`` is `Node.command`: it numbers it)."""
        return command(m.CarDrive, v=self.v, steer=self.steer)


def common_key(drive: Drive | CarKeys, key: bytes) -> str | None:
    """The keys both modes share: quit, the lab's stop, stop (and the terminal losing focus), the
    mode switch; None for any other key."""
    if key in QUIT_KEYS:
        return "quit"
    if key == LAB_STOP_KEY:
        return "lab stop"
    if key in STOP_KEYS or key == FOCUS_OUT:
        drive.stop("stopped" if key != FOCUS_OUT else "stopped: the terminal lost focus")
        return "stop"
    if key == MODE_KEY:
        drive.stop("stopped: switched mode")
        return "mode"
    return None


def split_keys(data: bytes) -> list[bytes]:
    """The keys in one read from the terminal: escape sequences (arrows, focus) kept whole."""
    out, i = [], 0
    while i < len(data):
        if data[i:i + 2] == b"\x1b[" and i + 2 < len(data):
            out.append(data[i:i + 3])
            i += 3
        else:
            out.append(data[i:i + 1])
            i += 1
    return out


KEY_TABLE = __doc__.split("\n\n")[1]
CAR_KEY_TABLE = next(block for block in __doc__.split("\n\n") if block.lstrip().startswith("w / Up      faster"))


@dataclass
class Bus:
    """What teleop sends and hears, for `drive_loop`."""

    publishers: dict[keys.Topic, Publisher[Any]]
    """cmd/twist, cmd/car and cmd/stop."""
    command: Callable[..., m.Command]
    """`Node.command`: numbers each command, so a stop wins over a motion sent before it."""
    pose: Subscription[m.Pose]
    """The robot's ``odom/pose``."""
    car_state: Subscription[m.CarState]
    """The robot's ``car/state``."""

    def put(self, message: m.Command, topic: keys.Topic) -> None:
        self.publishers[topic].put(message)

    def stop(self) -> None:
        self.put(self.command(m.Stop), keys.STOP)


async def teleop(args: argparse.Namespace, config: RobotConfig) -> int:
    fd = sys.stdin.fileno()
    if not os.isatty(fd):
        raise IcefloeError("teleop reads keys from a terminal: run it in one (its input is not a terminal)")
    rim = config.hwbridge.max_wheel_speed
    drive = Drive(speed=min(args.speed, rim), turn=min(args.turn, 2 * rim / config.geometry.track),
                  max_speed=rim, max_turn=2 * rim / config.geometry.track, hold=args.hold)
    car = CarKeys(max_speed=rim, max_steer=config.car.max_steer, wheelbase=config.car.wheelbase)
    robot = args.robot or config.name
    if not keys.is_concrete(robot) or any(c in robot for c in "$?#/"):
        raise IcefloeError(f"--robot {robot!r}: name one robot (a TA's credentials name none: give --robot)")
    # Its keys are the named robot's: --robot drives that robot, not the config's (nor, for the TA, "*").
    config = msgspec.structs.replace(config, name=robot)
    async with Node("teleop", config, retry=False) as node:
        if problem := check_robot(await node.alive("*"), robot):
            warn(problem)
        stop = node.publisher(keys.STOP)
        bus = Bus({keys.TWIST: node.publisher(keys.TWIST), keys.CAR: node.publisher(keys.CAR), keys.STOP: stop},
                  node.command, node.subscribe(keys.ODOM_POSE, robot=robot),
                  node.subscribe(keys.CAR_STATE, robot=robot))
        print("\n".join(mode_lines(car if args.car else drive)), flush=True)
        how = (f"as a car (wheelbase {car.wheelbase:g} m, max_steer {car.max_steer:g} rad)" if args.car else
               f"hold a key to drive (stops {args.hold:g} s after the last one)")
        print(f"driving {robot!r} {how}; m switches modes", flush=True)
        keys_in: asyncio.Queue[bytes] = asyncio.Queue()
        loop = asyncio.get_running_loop()
        saved = termios.tcgetattr(fd)
        tty.setcbreak(fd)  # keys one by one, no echo; Ctrl-C still interrupts
        sys.stdout.write(FOCUS_REPORTING[0])

        def readable() -> None:
            data = os.read(fd, 64)
            for key in split_keys(data) if data else [b"\x04"]:  # end of input: as Ctrl-D
                keys_in.put_nowait(key)

        loop.add_reader(fd, readable)
        quit_ = asyncio.Event()
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            loop.add_signal_handler(sig, quit_.set)
        try:
            await drive_loop(drive, car, args.car, keys_in, quit_, bus, 1.0 / args.rate,
                             lambda: lab_hold(node, config.lab.timeout))
        finally:
            stop.put(node.command(m.Stop))  # whatever ended teleop: the wheels stop
            loop.remove_reader(fd)
            for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
                loop.remove_signal_handler(sig)
            with contextlib.suppress(OSError):
                sys.stdout.write(FOCUS_REPORTING[1] + "\r\x1b[K" + "stopped; bye\n")
                sys.stdout.flush()
                termios.tcsetattr(fd, termios.TCSADRAIN, saved)
            await asyncio.sleep(0.2)  # the stop leaves before the session closes
    return 0


async def lab_hold(node: Node, timeout: float) -> list[str]:
    """The ``!`` key: hold every robot alive on the bus stopped (`labstop.stop`), each given ``timeout``
    s to confirm (``[lab] timeout`` of the config); the lines to print."""
    answers = await labstop.stop(node, node.command(m.LabStop, action="hold", reason="teleop's ! key",
                                                    timeout=timeout))
    if not answers:
        return ["lab stop: no robot's hwbridge is alive on the bus"]
    lines = [f"lab stop: {a.line()}" for a in answers]
    if not any(a.confirmed for a in answers):
        lines.append("lab stop: no robot answered: only the lab's TA account may (--credentials ta.credentials)")
    return [*lines, f"lab stop: {labstop.summary(answers, 'hold')}; `icefloe lab release` ends the holds"]


def mode_lines(driver: Drive | CarKeys) -> list[str]:
    """What to print when the mode changes: the new mode's keys."""
    if isinstance(driver, CarKeys):
        return ["car mode (cmd/car): keys steer, not spin; the car keeps its speed until space or speed 0:",
                CAR_KEY_TABLE]
    return ["unicycle mode (cmd/twist): hold a key to drive:", KEY_TABLE]


async def drive_loop(drive: Drive, car: CarKeys, car_first: bool, keys_in: asyncio.Queue[bytes],
                     quit_: asyncio.Event, bus: Bus, period: float,
                     lab_stop: Callable[[], Awaitable[list[str]]] | None = None) -> None:
    """Keys in, commands out (``cmd/twist`` in the unicycle mode, ``cmd/car`` in the car mode),
    every ``period`` s while moving; returns on a quit key or signal. ``lab_stop`` (the ``!``
    key) returns lines to print above the status line."""
    latest: m.Pose | None = None
    driver: Drive | CarKeys = car if car_first else drive
    printed: list[str] = []
    asking: set[asyncio.Task[list[str]]] = set()

    def said(task: asyncio.Task[list[str]]) -> None:
        asking.discard(task)
        if not task.cancelled():
            printed.extend(task.result() if task.exception() is None else [f"lab stop: {task.exception()}"])

    async def follow_pose() -> None:
        nonlocal latest
        async for p in bus.pose:
            latest = p

    async def follow_car() -> None:
        async for state in bus.car_state:
            car.applied = state

    followers = [asyncio.create_task(follow_pose()), asyncio.create_task(follow_car())]
    shown = ""
    try:
        next_send = 0.0
        while not quit_.is_set():
            with contextlib.suppress(TimeoutError):
                key = await asyncio.wait_for(keys_in.get(), period / 2)
                now = time.monotonic()
                what = driver.key(key, now)
                if what == "quit":
                    return
                if what == "lab stop" and lab_stop is not None:
                    bus.stop()  # this robot at once, the others as they answer
                    driver.stop("stopped: the lab's stop (!) asked every robot")
                    task = asyncio.ensure_future(lab_stop())
                    asking.add(task)
                    task.add_done_callback(said)
                if what in ("stop", "mode"):
                    bus.stop()
                if what == "mode":
                    driver = drive if driver is car else car
                    driver.stop("stopped")
                    printed.extend(mode_lines(driver))
                if what == "move":
                    next_send = 0.0  # at once
            now = time.monotonic()
            if driver.expired(now):
                bus.stop()
            if driver.moving and now >= next_send:
                bus.put(driver.message(bus.command), driver.topic)
                next_send = now + period
            where = f"  x {latest.x:+.2f} y {latest.y:+.2f} m" if latest else ""
            while printed:  # above the status line, which is drawn again below them
                sys.stdout.write("\r\x1b[K" + printed.pop(0) + "\n")
                shown = ""
            if (line := driver.line() + where) != shown:  # only what changed: a terminal over Wi-Fi is slow
                sys.stdout.write("\r" + line + "\x1b[K")
                sys.stdout.flush()
                shown = line
    finally:
        for follower in followers:
            follower.cancel()
        for task in asking:
            task.cancel()


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("teleop", help="drive a robot from the keyboard (arrows/WASD, space stops)",
                         description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_bus_arguments(p)
    p.add_argument("--speed", type=float, default=0.15, metavar="M/S",
                   help="forward speed to start with, m/s (default 0.15; at most the robot's max_wheel_speed)")
    p.add_argument("--turn", type=float, default=1.0, metavar="RAD/S",
                   help="turn rate to start with, rad/s (default 1.0)")
    p.add_argument("--hold", type=float, default=0.8, metavar="S",
                   help="stop when no key came for this long, s (default 0.8)")
    p.add_argument("--rate", type=float, default=10.0, metavar="HZ",
                   help="send cmd/twist (cmd/car) this often while driving (default 10; the robot's deadman is 0.5 s)")
    p.add_argument("--car", action="store_true",
                   help="start in the car mode: drive the robot's virtual car (cmd/car, [car] of its config); "
                        "m switches modes")
    p.set_defaults(run=on_bus(teleop))
