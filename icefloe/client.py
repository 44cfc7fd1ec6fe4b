"""Drive a robot from Python without learning Zenoh first.

In the spirit of the PenguinPi's ``PiBot`` class::

    from icefloe.client import Robot

    with Robot("penguin1", connect="tcp/10.0.0.5:7447") as robot:
        robot.set_velocity(0.1, 0.1, duration=2.0)   # m/s each wheel, blocks for 2 s
        print(robot.pose)                             # x, y in m, theta in rad (CCW positive)
        frame = robot.image()                         # numpy BGR array

`Robot` blocks (it runs its own event loop in a background thread); `AsyncRobot`
is the same robot for ``asyncio`` code (``async with AsyncRobot(...) as robot``).
Both are thin: every call is one message on the bus, listed in each docstring, so
a student can later do the same with raw Zenoh in any language.

Every command carries who sent it (``sender``: this client's Zenoh session id),
its number (``seq``) and when it was issued (``stamp``), so that the robot puts a
stop and the commands around it in the order they were issued, whatever path
each took on the bus (docs/hwbridge.md, "Which command wins").

Errors: `icefloe.errors.NotReachable` (naming the endpoint or key) when the robot
or one of its services does not answer in time; `icefloe.errors.NotConfirmed`
when the robot could not confirm a stop; `ValueError` naming the argument for a
bad argument (nothing is sent then).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import functools
import inspect
import logging
import math
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Coroutine, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import cv2
import msgspec
import numpy as np
import zenoh

from . import config as config_mod
from .config import RobotConfig, robot_info
from .credentials import read as read_credentials
from .errors import BadPayload, ConfigError, IcefloeError, MotionStopped, MotionTimeout, NotConfirmed, NotReachable
from .logs import LimitedLog
from .runtime import Node, open_session, why_unreachable
from .schemas import keys
from .schemas import messages as m
from .schemas.keys import Topic

T = TypeVar("T")
C = TypeVar("C", bound=m.Command)

CONFIRM_WAIT = 3.0
"""How long hwbridge tries to confirm a stop before it answers that it could not, s: `AsyncRobot.stop`
waits that much longer than its ``timeout``, so that a slow confirmation on a busy robot still
arrives, and a failed one arrives with hwbridge's reason."""

CONNECT_TIMEOUT = 1.0
"""How long `AsyncRobot.open` retries a router that does not answer, by default, s: long enough
for a router that is starting, short enough that a script run without a robot says so at once."""
WAITING_NOTICE_S = 30.0
"""How often a program waiting for its router says so, s (the first time after 1 s)."""


class Encoders(NamedTuple):
    """Wheel encoder counts, unwrapped (they never wrap); 384 per wheel turn on the PenguinPi."""

    left: int
    right: int


def _config(name: str | None, connect: str | Sequence[str] | None,
            config: str | Path | RobotConfig | None, credentials: str | Path | None) -> RobotConfig:
    """The robot config from a name, an endpoint, a config file and/or a credentials file."""
    cfg = config if isinstance(config, RobotConfig) else config_mod.load(config)
    if credentials is not None:  # robot name, user, password and endpoint of a robot we may drive
        creds = read_credentials(credentials)
        cfg = msgspec.structs.replace(cfg, name=creds.robot, zenoh=msgspec.structs.replace(
            cfg.zenoh, user=creds.user, password=creds.password,
            connect=creds.connect or cfg.zenoh.connect))
    if name is not None:
        if not isinstance(name, str) or not name or "/" in name or "*" in name:
            raise ValueError(f"name: {name!r} is not a robot name (e.g. 'penguin1')")
        cfg = msgspec.structs.replace(cfg, name=name)
    if connect is not None:
        endpoints = [connect] if isinstance(connect, str) else list(connect)
        for e in endpoints:
            if "/" not in e:
                raise ValueError(f"connect: {e!r} is not a Zenoh endpoint (e.g. 'tcp/10.0.0.5:7447')")
        cfg = msgspec.structs.replace(cfg, zenoh=msgspec.structs.replace(cfg.zenoh, connect=endpoints))
    return cfg


def add_robot_arguments(parser: argparse.ArgumentParser) -> None:
    """``--config``, ``--robot``, ``--connect``, ``--credentials``: which robot a script talks to.

    Pass the parsed arguments to ``Robot(**robot_arguments(args))``."""
    parser.add_argument("--config", help="robot config file (default: the simulated robot)")
    parser.add_argument("--robot", help="robot name, e.g. penguin1")
    parser.add_argument("--connect", help="Zenoh endpoint of the robot, e.g. tcp/10.0.0.5:7447")
    parser.add_argument("--credentials", help="the robot's credentials file (robots with access control)")


def robot_arguments(args: argparse.Namespace) -> dict[str, Any]:
    """The `Robot` / `AsyncRobot` arguments from what `add_robot_arguments` parsed."""
    return {"name": args.robot, "connect": args.connect, "config": args.config, "credentials": args.credentials}


def _number(name: str, value: object) -> float:
    """``value`` as a finite float, or a ValueError naming the argument."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.number):
        raise ValueError(f"{name}: expected a number, got {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"{name}: must be a finite number, got {value!r}")
    return number


class _Latest:
    """The newest message of one topic, and an event set when the first one arrives."""

    def __init__(self, topic: Topic) -> None:
        self.topic = topic
        self.value: Any = None
        self.arrived = asyncio.Event()
        self.callbacks: list[Callable[[Any], object]] = []
        self.followed = False
        """True once a task keeps this topic's latest value."""


OPTIONAL_STATE = (keys.SLAM_POSE, keys.SLAM_MAP, keys.MAP_LANDMARKS, keys.EXTLOC_POSE, keys.CAR_STATE)
"""Kept like the robot's state, but from services a robot may not run (slam, mapper, a lab's extloc), or
that comes only once a second while nothing happens (``car/state``): `ready()` waits for them only when named."""

BLINK_MIN_S = 0.05
"""Shortest on or off time of a blinking LED, s (hwbridge takes LED commands every 20 ms)."""


class Leds:
    """The board's LEDs: ``robot.leds[2] = True`` publishes ``io/leds``.

    Reading ``robot.leds[2]`` gives what this client last set (the board does not
    report LED states on the bus). Setting or pulsing an LED ends its blinking.
    """

    def __init__(self, publish: Callable[[m.Led], None]) -> None:
        self._publish = publish
        self._state: dict[int, bool] = {}
        self._lock = threading.Lock()
        """Setters may run on the user's thread, blinking on the loop: one change at a time."""
        self._blinking: dict[int, object] = {}
        """LED -> token of the blink that owns it; a setter replaces it, and the blink ends."""

    def _check(self, led: object) -> int:
        if isinstance(led, bool) or not isinstance(led, int) or not 1 <= led <= 4:
            raise ValueError(f"led: expected 1 (red) or 2..4 (yellow), got {led!r}")
        return led

    def __getitem__(self, led: int) -> bool:
        return self._state.get(self._check(led), False)

    def __setitem__(self, led: int, on: bool) -> None:
        led = self._check(led)
        with self._lock:
            self._blinking.pop(led, None)
            self._put(led, bool(on))

    def _put(self, led: int, on: bool, pulse: float = 0.0) -> None:
        self._publish(m.Led(led=led, on=on, pulse=pulse))
        self._state[led] = on and not pulse

    def pulse(self, led: int, seconds: float) -> None:
        """Light ``led`` for ``seconds`` (0 < seconds <= 0.255 on the PenguinPi), then off."""
        led = self._check(led)
        seconds = _number("seconds", seconds)
        if not 0 < seconds <= 0.255:
            raise ValueError(f"seconds: must be in (0, 0.255], got {seconds}")
        with self._lock:
            self._blinking.pop(led, None)
            self._put(led, True, seconds)

    async def blink(self, led: int, on_s: float, off_s: float, times: int | None) -> None:
        """Blink ``led`` (run as a task): ``on_s`` lit, ``off_s`` dark, ``times`` times (None: until
        the LED is set again); it ends dark."""
        token = object()
        with self._lock:
            self._blinking[led] = token
        count = 0
        while times is None or count < times:
            for on, seconds in ((True, on_s), (False, off_s)):
                with self._lock:
                    if self._blinking.get(led) is not token:
                        return  # somebody set this LED since: it is theirs now
                    self._put(led, on)
                await asyncio.sleep(seconds)
            count += 1
        with self._lock:
            if self._blinking.get(led) is token:
                del self._blinking[led]

    def stop_blinking(self) -> None:
        """End every blink, leaving those LEDs dark (when the client closes)."""
        with self._lock:
            for led in list(self._blinking):
                del self._blinking[led]
                self._put(led, False)

    def __repr__(self) -> str:
        return f"Leds({self._state})"


BUTTON_NAMES = {"S1": 0, "S2": 1, "S3": 2, "S4": 3, "SDN": 10}
"""The robot's buttons by the names printed on the board, and their numbers on ``io/buttons``."""
MAX_CALLS_PER_MESSAGE = 16
"""At most this many ``when_pressed`` calls for one ``io/buttons`` message (it may count many presses)."""
MAX_PENDING_CALLS = 64
"""The blocking `Robot` keeps at most this many calls of one callback waiting for its thread."""


def _callback(what: str, callback: object, arg: object) -> Callable[[], object] | None:
    """``callback`` as a function of no arguments: gpiozero style, it may take none or one (``arg``)."""
    if callback is None:
        return None
    if not callable(callback):
        raise ValueError(f"{what}: expected a function (or None), got {callback!r}")
    try:
        signature = inspect.signature(callback)
    except (TypeError, ValueError):  # some built-ins have none: call them without arguments
        return callback
    with contextlib.suppress(TypeError):
        signature.bind()
        return callback
    with contextlib.suppress(TypeError):
        signature.bind(arg)
        return functools.partial(callback, arg)
    raise ValueError(f"{what}: {callback!r} must take no argument, or one (the button)")


class Button:
    """One button of the robot, as gpiozero's ``Button``: ``robot.buttons["S4"].when_pressed = hello``.

    ``when_pressed`` / ``when_released``: a function of no argument (or of one: this button),
    plain or async, called for each press / release. ``presses``: presses seen since this
    client connected. ``is_pressed``: True/False for buttons that report releases, None for
    the others. Which is which: the PenguinPi's S4 (3) reports presses only (its firmware
    counts them); the shutdown button SDN (10) reports both (through the power service), but
    held for ``power.button_hold_s`` (0.5 s) it shuts the robot down; S1..S3 act on the board
    itself and are not reported.
    """

    def __init__(self, number: int, name: str) -> None:
        self.number = number
        self.name = name
        self.reports_releases = number == BUTTON_NAMES["SDN"]
        self.presses = 0
        self.is_pressed: bool | None = False if self.reports_releases else None
        self._when_pressed: Callable[[], object] | None = None
        self._when_released: Callable[[], object] | None = None
        self._given: dict[str, object] = {"when_pressed": None, "when_released": None}
        self._pressed = asyncio.Event()
        """Set, and replaced by a new one, at each press (for `AsyncRobot.wait_for_press`)."""

    @property
    def when_pressed(self) -> object:
        return self._given["when_pressed"]

    @when_pressed.setter
    def when_pressed(self, callback: object) -> None:
        self._when_pressed = _callback(f"{self.name}.when_pressed", callback, self)
        self._given["when_pressed"] = callback

    @property
    def when_released(self) -> object:
        return self._given["when_released"]

    @when_released.setter
    def when_released(self, callback: object) -> None:
        if callback is not None and not self.reports_releases:
            raise ValueError(f"{self.name}.when_released: {self.name} reports presses only (the board counts "
                             f"them); of the robot's buttons only SDN (10) reports releases")
        self._when_released = _callback(f"{self.name}.when_released", callback, self)
        self._given["when_released"] = callback

    def __repr__(self) -> str:
        state = "" if self.is_pressed is None else f", pressed={self.is_pressed}"
        return f"<Button {self.name} ({self.number}): {self.presses} presses{state}>"


class Buttons:
    """The robot's buttons, by name (``"S4"``, ``"SDN"``) or by number (3, 10): ``robot.buttons["S4"]``."""

    def __init__(self) -> None:
        self._buttons = {number: Button(number, name) for name, number in BUTTON_NAMES.items()}

    def __getitem__(self, button: int | str) -> Button:
        number = BUTTON_NAMES.get(button, button) if isinstance(button, str) else button
        if isinstance(number, bool) or number not in self._buttons:
            raise ValueError(f"button: expected one of {', '.join(BUTTON_NAMES)} or its number "
                             f"({', '.join(map(str, BUTTON_NAMES.values()))}), got {button!r}")
        return self._buttons[number]

    def __iter__(self) -> Iterator[Button]:
        return iter(self._buttons.values())

    def __repr__(self) -> str:
        return f"Buttons({', '.join(repr(b) for b in self)})"


CREEP_SPEED = 0.05
"""Rim speed of the last millimetres of `AsyncRobot.forward` and `turn`, and of their corrections,
m/s: slow enough to stop on the spot, fast enough for the motors (drive_square.py uses it too)."""
SLOW_DOWN_S = 0.3
"""Closed-loop moves slow down once the rest would take less than this at full speed, s."""
STOP_LAG_S = 0.12
"""A closed-loop move sends its stop this long before odometry says it arrives, s: what the
stop takes to reach the wheels, and odometry to report them (measured in the simulator)."""
STILL_SPEED, STILL_RATE = 0.002, 0.01
"""At rest: odometry speed below this (m/s) and turn rate below this (rad/s)."""
FORWARD_TOLERANCE, TURN_TOLERANCE = 0.005, math.radians(3.0)
"""A closed-loop move that stopped short by more than this (m, rad) goes on at `CREEP_SPEED`."""
CORRECTIONS = 1
"""At most this many corrections after the first stop."""
STEER = 3.0
"""`forward` holds its heading: turn rate per radian of heading error, (rad/s)/rad."""


class _Straight:
    """`AsyncRobot.forward`'s goal: rim travel along the start heading, measured on odometry."""

    def __init__(self, start: m.Pose, track: float) -> None:
        self.start, self.track = start, track
        self.wheels = (1.0, 1.0)  # left, right for positive progress

    def progress(self, pose: m.Pose) -> float:
        """m driven along the start heading."""
        s = self.start
        return (pose.x - s.x) * math.cos(s.theta) + (pose.y - s.y) * math.sin(s.theta)

    def rim_speed(self, pose: m.Pose) -> float:
        return abs(pose.v)

    def steer(self, pose: m.Pose) -> float:
        """Wheel speed difference (right minus left, halved) that turns back to the start heading, m/s."""
        error = math.remainder(pose.theta - self.start.theta, math.tau)
        return -STEER * error * self.track / 2

    def show(self, rim: float) -> str:
        return f"{rim:.3f} m"


class _Spin(_Straight):
    """`AsyncRobot.turn`'s goal: heading change, as rim travel (rad x track / 2), counted through ±180°."""

    def __init__(self, start: m.Pose, track: float) -> None:
        super().__init__(start, track)
        self.wheels = (-1.0, 1.0)
        self._theta, self._turned = start.theta, 0.0

    def progress(self, pose: m.Pose) -> float:
        self._turned += math.remainder(pose.theta - self._theta, math.tau)
        self._theta = pose.theta
        return self._turned * self.track / 2

    def rim_speed(self, pose: m.Pose) -> float:
        return abs(pose.w) * self.track / 2

    def steer(self, pose: m.Pose) -> float:
        return 0.0

    def show(self, rim: float) -> str:
        return f"{math.degrees(rim / (self.track / 2)):.1f}°"


class _Move:
    """A closed-loop move in progress; `cut` says what ended it early."""

    def __init__(self) -> None:
        self.cut: str | None = None


class AsyncRobot:
    """One robot on the bus, for asyncio code. ``async with AsyncRobot("sim") as robot: ...``

    ``name``: the robot's name (keys are ``icefloe/<name>/...``); ``connect``: the
    Zenoh endpoint of its router; ``config``: a robot config (file, name or
    `RobotConfig`) to take both from; ``credentials``: the robot's credentials
    file (name, user, password, endpoint), needed to drive a robot with access
    control (without it you may only watch). ``timeout`` (s) bounds every wait.
    """

    def __init__(self, name: str | None = None, *, connect: str | Sequence[str] | None = None,
                 config: str | Path | RobotConfig | None = None,
                 credentials: str | Path | None = None, timeout: float = 5.0,
                 service: str = "client", clamp: bool = False, follow: bool = True) -> None:
        """``clamp``: leave speeds beyond the robot's limit to the robot, which clamps them (the
        web API does: old clients count on that); by default they raise ValueError here.
        ``follow``: keep the latest pose, wheels, battery, landmarks, localized pose and DIP
        from `open` on (False: the web API, which subscribes only while an HTTP client reads)."""
        try:
            self.config = _config(name, connect, config, credentials)
        except ConfigError as exc:
            raise ValueError(f"config: {exc}") from None
        self.name = self.config.name
        self.timeout = _number("timeout", timeout)
        self.node = Node(service, self.config)
        self._latest = {t.name: _Latest(t) for t in
                        (keys.ODOM_POSE, keys.WHEELS, keys.HW_BATTERY, keys.LANDMARKS, keys.IMAGE,
                         keys.LOC_POSE, keys.DIP, *OPTIONAL_STATE)}
        self._tasks: list[asyncio.Task[None]] = []
        self._hold: asyncio.Task[None] | None = None
        self._moved = False
        self.leds: Leds
        self.clamp = clamp
        self.follow = follow
        self.buttons = Buttons()
        """The robot's buttons (see `Button`): ``robot.buttons["S4"].when_pressed = hello``."""
        self._info: m.RobotInfo | None = None
        self._info_source = ""
        self._moving: _Move | None = None
        self._dispatch: Callable[[Callable[..., object], tuple[Any, ...]], None] | None = None
        """Set by the blocking `Robot`: runs plain callbacks on its callback thread."""

    # ------------------------------------------------------------------ connection

    async def open(self, connect_timeout: float | None = None) -> AsyncRobot:
        """Connect to the robot's router; `NotReachable` naming the endpoint and the likely fix after
        ``connect_timeout`` s (default: ``timeout``, at most `CONNECT_TIMEOUT`; ``math.inf``: wait
        for good, as a service does).
        """
        endpoints = ", ".join(self.config.zenoh.connect)
        if connect_timeout is None:
            connect_timeout = min(self.timeout, CONNECT_TIMEOUT)
        start = time.monotonic()
        deadline, notice_at = start + connect_timeout, start + 1.0
        while True:  # the router may be starting (robot just booted): retry until the deadline
            try:
                probe = await open_session(self.config, retry=False)
                probe.close()
                break
            except NotReachable:
                now = time.monotonic()
                if now > deadline:
                    why = why_unreachable(self.config, self.config.zenoh.connect)
                    raise NotReachable(f"robot {self.name!r}: no Zenoh router answers at {endpoints} "
                                       f"within {connect_timeout} s: {why}") from None
                if now >= notice_at:  # a service waiting for good says so, now and then
                    notice_at = now + WAITING_NOTICE_S
                    logging.getLogger("icefloe").warning(
                        "waiting for the Zenoh router of robot %r at %s: %s", self.name, endpoints,
                        why_unreachable(self.config, self.config.zenoh.connect))
                await asyncio.sleep(0.2)
        await self.node.__aenter__()  # the router answers: this opens at once
        self._wheels = self.node.publisher(keys.WHEELS_CMD)
        self._car = self.node.publisher(keys.CAR)
        self._stop = self.node.publisher(keys.STOP)
        self._oled = self.node.publisher(keys.OLED_TEXT)
        self.leds = Leds(self.node.publisher(keys.LEDS).put)
        for name in self._latest if self.follow else ():
            if name != keys.IMAGE.name:  # images are big: only once someone asks for one
                self._follow(name)
        self._tasks.append(asyncio.create_task(self._follow_buttons()))
        # Somebody else's stop (a tool, another program) must end our held velocity.
        # Our own stops come back to us too; REMOTE ignores them.
        loop = asyncio.get_running_loop()

        def on_stop(_sample: zenoh.Sample) -> None:  # the node's reader thread: hand over to the loop
            with contextlib.suppress(RuntimeError):  # the loop is closing
                loop.call_soon_threadsafe(self._end_hold, "a cmd/stop from another program")

        self.node.on_samples(self.node.key(keys.STOP), on_stop, allowed_origin=zenoh.Locality.REMOTE)
        return self

    async def close(self) -> None:
        """Stop the wheels if this client moved them, end blinking LEDs, and close the session."""
        if hasattr(self, "leds"):
            self.leds.stop_blinking()
        if self._moved and hasattr(self, "_stop"):
            self._end_hold()
            self._stop.put(self.command(m.Stop))
        for task in self._tasks:
            task.cancel()
        self._end_hold()
        self.node.close()

    async def __aenter__(self) -> AsyncRobot:
        try:
            return await self.open()
        except BaseException:
            await self.close()
            raise

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    def _follow(self, name: str) -> None:
        """Start keeping the latest message of topic ``name`` (once)."""
        latest = self._latest[name]
        if not latest.followed:
            latest.followed = True
            self._tasks.append(asyncio.create_task(self._keep(latest)))

    async def _keep(self, latest: _Latest) -> None:
        async for msg in self.node.subscribe(latest.topic, latest=True):
            latest.value = msg
            latest.arrived.set()
            for callback in list(latest.callbacks):
                try:
                    result = callback(msg)
                    if inspect.isawaitable(result):
                        await result
                except Exception as exc:  # a student's callback must not end the subscription
                    self.callback_failed(callback, exc)

    async def _fire(self, callback: Callable[..., object], *args: Any) -> None:
        """Call a user's callback: on the blocking `Robot`'s callback thread if there is one (plain
        functions), else here, in the loop (awaited if async). Its exceptions are logged, never raised."""
        if self._dispatch is not None and not inspect.iscoroutinefunction(callback):
            self._dispatch(callback, args)
            return
        try:
            result = callback(*args)
            if inspect.isawaitable(result):
                await result
        except Exception as exc:  # a student's callback must not end the subscription
            self.callback_failed(callback, exc)

    def callback_failed(self, callback: Callable[..., object], exc: Exception) -> None:
        """Log a user's callback that raised, with its traceback: a few a second per callback and
        then a count (`LimitedLog`), as a callback that fails at every pose would fail 50 times a second."""
        name = getattr(callback, "__qualname__", type(callback).__name__)
        self.node.limited.error(f"callback {name}", "callback %r failed", callback, exc_info=exc)

    async def _follow_buttons(self) -> None:
        """``io/buttons`` -> the `Button` objects: counts, state, callbacks, waiters."""
        async for msg in self.node.subscribe(keys.BUTTONS, latest=False):
            try:
                button = self.buttons[msg.button]
            except ValueError:
                continue  # a button this client does not know (another board's)
            if msg.event == "release":
                if not button.reports_releases:
                    continue  # not from its board: S4 has no way to report one
                button.is_pressed = False
                if button._when_released is not None:
                    await self._fire(button._when_released)
                continue
            presses = max(0, msg.presses)
            button.presses += presses
            if button.reports_releases:
                button.is_pressed = True
            if presses:
                pressed, button._pressed = button._pressed, asyncio.Event()
                pressed.set()
            for _ in range(min(presses, MAX_CALLS_PER_MESSAGE)):
                if button._when_pressed is not None:
                    await self._fire(button._when_pressed)

    async def ready(self, *names: str, timeout: float | None = None) -> None:
        """Wait until ``names`` ("odom/pose", "hw/wheels", ...) have each sent a first message."""
        optional = {t.name for t in OPTIONAL_STATE}  # only if asked for: their services may not run
        for name in names or tuple(n for n in self._latest if n not in optional):
            latest = self._latest[name]
            try:
                await asyncio.wait_for(latest.arrived.wait(), timeout or self.timeout)
            except TimeoutError:
                raise NotReachable(f"nothing on {self.node.key(latest.topic)} within "
                                   f"{timeout or self.timeout} s (is the service running?)") from None

    # ------------------------------------------------------------------ state (latest values)

    @property
    def pose(self) -> m.Pose | None:
        """Latest ``odom/pose``: x, y (m), theta (rad, CCW positive), v (m/s), w (rad/s)."""
        return self._latest[keys.ODOM_POSE.name].value

    @property
    def encoders(self) -> Encoders | None:
        """Latest encoder counts from ``hw/wheels`` (unwrapped)."""
        w = self._latest[keys.WHEELS.name].value
        return None if w is None else Encoders(w.ticks_left, w.ticks_right)

    @property
    def wheels(self) -> m.Wheels | None:
        """Latest ``hw/wheels``: counts, measured and commanded rim speeds (m/s)."""
        return self._latest[keys.WHEELS.name].value

    @property
    def battery(self) -> m.BatteryReading | None:
        """Latest ``hw/battery``: voltage (V) and current (A)."""
        return self._latest[keys.HW_BATTERY.name].value

    @property
    def landmarks(self) -> list[m.Landmark] | None:
        """Markers in the latest ``camera/landmarks``: id, range (m), bearing (rad, CCW positive)."""
        msg = self._latest[keys.LANDMARKS.name].value
        return None if msg is None else msg.landmarks

    @property
    def localized_pose(self) -> m.PoseEstimate | None:
        """Latest ``loc/pose``, the localizer's pose in the map (the world file's frame): x, y (m),
        theta (rad, CCW), and its 3x3 covariance. Unlike `pose` (odometry) it does not drift:
        it is corrected by the ArUco markers the camera sees."""
        return self._latest[keys.LOC_POSE.name].value

    @property
    def external_pose(self) -> m.ExternalPose | None:
        """Latest ``extloc/pose``: the robot's pose as the lab's overhead camera saw it (x, y in m,
        theta in rad, in the world frame, with its 3x3 covariance; docs/extloc.md). Ground truth
        for your own estimates; None until the robot has been seen (and it is not repeated while
        the robot is out of view: check its ``stamp``)."""
        return self._latest[keys.EXTLOC_POSE.name].value

    @property
    def slam_pose(self) -> m.PoseEstimate | None:
        """Latest ``slam/pose``: SLAM's x, y (m), theta (rad) in its own frame (where it started),
        with the 3x3 covariance (services/slam, or a student's SLAM on the same key)."""
        return self._latest[keys.SLAM_POSE.name].value

    @property
    def slam_map(self) -> m.LandmarkMap | None:
        """Latest ``slam/map``: SLAM's landmarks (id, x, y m, 2x2 covariance m^2), in SLAM's frame."""
        return self._latest[keys.SLAM_MAP.name].value

    @property
    def landmark_map(self) -> m.LandmarkMap | None:
        """Latest ``map/landmarks``: the map maker's landmarks (id, x, y m, 2x2 covariance m^2)."""
        return self._latest[keys.MAP_LANDMARKS.name].value

    @property
    def dip(self) -> int | None:
        """Latest ``io/dip``: the DIP switches, 0..15 (SW1 = 8, SW2 = 4, SW3 = 2, SW4 = 1)."""
        msg = self._latest[keys.DIP.name].value
        return None if msg is None else msg.value

    async def wait_for_press(self, button: int | str = "S4", timeout: float | None = None) -> bool:
        """Wait for the next press of ``button`` (default S4, the user button); False after
        ``timeout`` s without one (None: wait for ever)."""
        b = self.buttons[button]
        if timeout is not None:
            timeout = _number("timeout", timeout)
        try:
            await asyncio.wait_for(b._pressed.wait(), timeout)
        except TimeoutError:
            return False
        return True

    async def image_jpeg(self, fresh: bool = False) -> m.Image:
        """The latest ``camera/image`` (JPEG); ``fresh``: wait for the next one."""
        latest = self._latest[keys.IMAGE.name]
        self._follow(keys.IMAGE.name)
        if not fresh:
            await self.ready(keys.IMAGE.name)
            return latest.value
        # One future per caller, so several callers (e.g. video streams) can each wait.
        future: asyncio.Future[m.Image] = asyncio.get_running_loop().create_future()

        def take(image: m.Image) -> None:
            if not future.done():
                future.set_result(image)

        latest.callbacks.append(take)
        try:
            return await asyncio.wait_for(future, self.timeout)
        except TimeoutError:
            raise NotReachable(f"no new frame on {self.node.key(keys.IMAGE)} within "
                               f"{self.timeout} s (is the camera service running?)") from None
        finally:
            latest.callbacks.remove(take)

    async def image(self, fresh: bool = False) -> np.ndarray:
        """The latest camera frame as a BGR numpy array (height x width x 3)."""
        jpeg = await self.image_jpeg(fresh)
        frame = await asyncio.to_thread(cv2.imdecode, np.frombuffer(jpeg.data, np.uint8), cv2.IMREAD_COLOR)
        if frame is None:
            raise ValueError(f"{self.node.key(keys.IMAGE)}: frame is not a decodable JPEG")
        return frame

    def on_pose(self, callback: Callable[[m.Pose], object]) -> Callable[[], None]:
        """Call ``callback(pose)`` (plain or async) for every new pose; returns a function that stops it."""
        callbacks = self._latest[keys.ODOM_POSE.name].callbacks

        def call(pose: m.Pose) -> Awaitable[None]:
            return self._fire(callback, pose)

        callbacks.append(call)
        return lambda: callbacks.remove(call) if call in callbacks else None

    # ------------------------------------------------------------------ commands

    def command(self, kind: type[C], **fields: Any) -> C:
        """A command message of type ``kind`` (`m.Twist`, `m.Stop`, ...) with ``fields``, numbered
        and stamped as this client's next command. For publishing a command yourself."""
        return self.node.command(kind, **fields)

    async def set_velocity(self, left: float, right: float, duration: float | None = None,
                           accel: float | None = None) -> m.MotionDone | None:
        """Drive the wheels at ``left``, ``right`` rim speeds (m/s, positive forward).

        Without ``duration`` the speeds hold until the next command or `stop`
        (``cmd/wheels``, re-sent well within the robot's deadman timeout). With
        ``duration`` (s) this is one ``cmd/motion`` query: ramp up over ``accel``
        seconds, hold, ramp down over ``accel``, stop; it returns when the motion
        has ended, with how it ended.
        """
        left, right = _number("left", left), _number("right", right)
        for side, speed in (("left", left), ("right", right)):
            await self._check_speed(side, speed)
        if duration is None:
            if accel is not None:
                raise ValueError("accel: only with a duration")
            self._end_hold()
            self._moved = True
            if left == 0 and right == 0:
                self._wheels.put(self.command(m.WheelSpeeds, left=0.0, right=0.0))
            else:
                self._hold = asyncio.create_task(self._hold_speeds(left, right))
            return None
        duration = _number("duration", duration)
        accel = 0.0 if accel is None else _number("accel", accel)
        if duration <= 0:
            raise ValueError(f"duration: must be > 0 s, got {duration}")
        if accel < 0:
            raise ValueError(f"accel: must be >= 0 s, got {accel}")
        if duration <= 2 * accel:
            raise ValueError(f"accel: each ramp ({accel} s) must be shorter than half the "
                             f"duration ({duration} s)")
        self._end_hold()
        self._moved = True
        motion = self.command(m.Motion, left=left, right=right, duration=duration, accel=accel)
        # The motion lasts duration + accel; allow for the bus and a busy robot.
        with self._stop_unless_done():
            return await self.node.query(keys.MOTION, motion, timeout=duration + accel + self.timeout)

    async def _hold_speeds(self, left: float, right: float) -> None:
        period = self.config.hwbridge.deadman_s / 4
        while True:
            self._wheels.put(self.command(m.WheelSpeeds, left=left, right=right))
            await asyncio.sleep(period)

    async def drive_car(self, v: float, steer: float, duration: float | None = None) -> None:
        """Drive as a car (``cmd/car``, the robot's virtual car: docs/motion-models.md): ``v`` m/s
        forward, the front wheel steered ``steer`` rad (left positive). The car turns on a circle of
        radius wheelbase / tan(steer); its steering turns towards ``steer`` at the car's steering
        rate, so a change of angle takes a moment.

        Without ``duration`` it holds until the next command or `stop` (re-sent well within the
        deadman); with ``duration`` (s) it drives that long, then stops and returns once the robot
        confirmed the stop (the wheels are stopped also if the call is cancelled). ValueError,
        naming the limit, for a ``v`` beyond the robot's ``max_wheel_speed`` or a ``steer`` beyond its
        car's ``max_steer`` (the robot would slow or clip them)::

            await robot.drive_car(0.2, 0.3)                 # a 0.48 m circle to the left, until stop()
            await robot.drive_car(0.2, -0.3, duration=2.0)  # to the right for 2 s, then stopped
        """
        v, steer = _number("v", v), _number("steer", steer)
        await self._check_speed("v", v)
        info = await self.info()
        if not self.clamp and info.max_steer and abs(steer) > info.max_steer:
            raise ValueError(f"steer: {steer} rad is beyond this robot's car.max_steer, {info.max_steer} rad "
                             f"({self._info_source})")
        if duration is not None and (duration := _number("duration", duration)) <= 0:
            raise ValueError(f"duration: must be > 0 s, got {duration}")
        self._end_hold()
        self._moved = True
        self._hold = asyncio.create_task(self._hold_car(v, steer))
        if duration is None:
            return
        try:
            await asyncio.sleep(duration)
        except BaseException:  # cancelled (Ctrl-C in the blocking Robot): the hold ends, the wheels stop
            self._end_hold("a cancelled drive_car()")
            self._halt()
            raise
        await self.stop()

    async def _hold_car(self, v: float, steer: float) -> None:
        period = self.config.hwbridge.deadman_s / 4
        while True:
            self._car.put(self.command(m.CarDrive, v=v, steer=steer))
            await asyncio.sleep(period)

    @contextlib.asynccontextmanager
    async def car(self, v: float = 0.0, steer: float = 0.0) -> AsyncIterator[AsyncRobot]:
        """Drive as a car while the block runs (`drive_car` with ``v``, ``steer``; call it again in
        the block to change them); when the block ends, however it ends (an exception, a
        cancellation), the robot is stopped, and the block's end waits for its confirmation::

            async with robot.car(0.2, 0.3):
                await asyncio.sleep(2.0)
                await robot.drive_car(0.2, -0.3)
                await asyncio.sleep(2.0)
            # stopped here
        """
        await self.drive_car(v, steer)
        try:
            yield self
        finally:
            self._end_hold("the end of a car() block")
            await self.stop()

    @property
    def car_state(self) -> m.CarState | None:
        """Latest ``car/state``: the virtual car's speed (m/s), steering now and its target (rad, after
        the rate limit and the clip), and the bicycle model's pose (x, y m, theta rad, from where
        hwbridge started), to compare with `pose` (odometry)."""
        return self._latest[keys.CAR_STATE.name].value

    def _end_hold(self, why: str = "another command from this program") -> None:
        """End a held velocity, and cut a closed-loop move short (it raises `MotionStopped` saying ``why``)."""
        if self._hold is not None:
            self._hold.cancel()
            self._hold = None
        if self._moving is not None and self._moving.cut is None:
            self._moving.cut = why

    def _halt(self) -> None:
        """``cmd/stop``, numbered after every command this client sent: it travels at Zenoh's
        real-time priority and can overtake a ``cmd/wheels`` of ours still on its way, but
        hwbridge refuses that older command when it arrives (docs/hwbridge.md, which command wins)."""
        self._stop.put(self.command(m.Stop))

    @contextlib.contextmanager
    def _stop_unless_done(self) -> Iterator[None]:
        """Stop the wheels if the block ends with an exception: a cancelled task (Ctrl-C in the
        blocking `Robot`), a timeout, a bug. A motion never outlives the call that started it."""
        try:
            yield
        except BaseException:
            self._halt()
            raise

    async def stop(self, confirm: bool = True) -> m.Wheels | None:
        """Stop the wheels now (``cmd/stop``); also ends a held velocity or a timed motion.

        With ``confirm`` (the default) it then asks hwbridge (``cmd/halt`` with ``rest =
        False``, the same stop) and returns once the board runs zero duty with its
        controller cleared, with the wheel state at that moment; `NotConfirmed` if
        hwbridge could not confirm it, `NotReachable` if hwbridge does not answer.
        """
        self._end_hold("stop()")
        stop = self.command(m.Stop)
        self._stop.put(stop)
        if not confirm:
            return None
        halt = m.Halt(sender=stop.sender, seq=stop.seq, stamp=stop.stamp, rest=False)
        try:
            return await self.node.query(keys.HALT, halt, timeout=self.timeout + CONFIRM_WAIT)
        except BadPayload as exc:  # hwbridge's answer: why it could not confirm
            raise NotConfirmed(str(exc)) from None

    async def reset_pose(self, x: float = 0.0, y: float = 0.0, theta: float = 0.0) -> m.Pose:
        """Reset the odometry pose (``odom/reset`` query) to x, y (m), theta (rad); returns it."""
        request = m.PoseReset(x=_number("x", x), y=_number("y", y), theta=_number("theta", theta))
        return await self.node.query(keys.ODOM_RESET, request, timeout=self.timeout)

    async def info(self) -> m.RobotInfo:
        """What this robot is (the ``info`` query, answered once): its board, wheel geometry and
        ``max_wheel_speed``, the limit every speed here is checked against. While the robot's
        info service does not answer: the same from this client's robot config."""
        if self._info is not None:
            return self._info
        try:
            self._info = await self.node.query(keys.INFO, m.Stop(), timeout=self.timeout)
            self._info_source = self.node.key(keys.INFO)
            return self._info
        except NotReachable:
            self._info_source = self.config.source or "the default robot config"
            return robot_info(self.config)

    async def _check_speed(self, name: str, speed: float) -> None:
        """ValueError naming ``name`` if ``speed`` (m/s) is beyond the robot's ``max_wheel_speed``."""
        if self.clamp:
            return
        limit = (await self.info()).max_wheel_speed
        if abs(speed) > limit:
            raise ValueError(f"{name}: {speed} m/s is beyond this robot's max_wheel_speed, {limit} m/s "
                             f"({self._info_source})")

    async def drive(self, v: float, w: float, duration: float | None = None,
                    accel: float | None = None) -> m.MotionDone | None:
        """Drive the body at ``v`` m/s forward while turning at ``w`` rad/s (CCW positive).

        The wheel speeds are ``v -/+ w * track / 2`` (the robot's track, from `info`), so this is
        `set_velocity` with those: held until the next command without ``duration``, one timed
        motion with it. ValueError, naming the limit, if a wheel would have to go faster than the
        robot's ``max_wheel_speed``::

            await robot.drive(0.1, 0.5)                  # a 0.2 m radius circle, until stop()
            await robot.drive(0.0, 1.0, duration=1.57)   # about a quarter turn, timed
        """
        v, w = _number("v", v), _number("w", w)
        info = await self.info()
        half = w * info.track / 2
        fastest = abs(v) + abs(half)
        limit = info.max_wheel_speed
        if fastest > limit and not self.clamp:
            raise ValueError(f"drive: v={v} m/s, w={w} rad/s needs a wheel at {fastest:.3f} m/s, beyond this "
                             f"robot's max_wheel_speed, {limit} m/s ({self._info_source}); at w={w} rad/s "
                             f"|v| can be {max(0.0, limit - abs(half)):.3f} m/s at most, and |w| is at most "
                             f"{2 * limit / info.track:.2f} rad/s")
        return await self.set_velocity(v - half, v + half, duration, accel)

    async def forward(self, distance: float, speed: float = 0.15, *, timeout: float | None = None) -> m.Pose:
        """Drive straight ``distance`` m (negative: backwards) at up to ``speed`` m/s, then stop.

        Closed loop on odometry (``odom/pose``): it holds the start heading, slows down near the
        end, sends the stop a little early (the wheels coast), and creeps on if it stopped more
        than 5 mm short. Returns the odometry pose once the robot is at rest. In the simulator it
        ends within 5 mm of the distance (docs/client.md). Raises `MotionTimeout` if it is not
        there within ``timeout`` s (default: three times the time it should take, plus 5 s),
        `MotionStopped` if a ``cmd/stop`` from another program or another command of this one
        ends it first; the wheels are stopped in every case, also when the call is cancelled::

            await robot.forward(0.3)           # 30 cm ahead
            await robot.forward(-0.1, 0.05)    # 10 cm back, slowly
        """
        distance, speed = _number("distance", distance), _number("speed", speed)
        if speed <= 0:
            raise ValueError(f"speed: must be > 0 m/s (the sign of distance says which way), got {speed}")
        await self._check_speed("speed", speed)
        return await self._closed_loop(f"forward({distance} m)", _Straight, distance, speed, timeout)

    async def turn(self, angle: float, speed: float = 1.0, *, timeout: float | None = None) -> m.Pose:
        """Turn on the spot by ``angle`` rad (counter-clockwise positive; any size, e.g. ``2 * math.pi``)
        at up to ``speed`` rad/s, then stop.

        Closed loop on odometry, like `forward` (it creeps on if it stopped more than 3° short);
        in the simulator it ends within about 6° of the angle: one encoder count is 0.4° of turn,
        and the wheels coast 2-5 mm after a stop. The same timeout and errors. ValueError if
        ``speed`` needs the wheels beyond ``max_wheel_speed``::

            await robot.turn(math.radians(90))     # a quarter turn left
            await robot.turn(-math.pi / 2, 0.5)    # a quarter turn right, slowly
        """
        angle, speed = _number("angle", angle), _number("speed", speed)
        if speed <= 0:
            raise ValueError(f"speed: must be > 0 rad/s (the sign of angle says which way), got {speed}")
        info = await self.info()
        half_track, limit = info.track / 2, info.max_wheel_speed
        if not self.clamp and speed * half_track > limit:
            raise ValueError(f"speed: {speed} rad/s needs the wheels at {speed * half_track:.3f} m/s, beyond this "
                             f"robot's max_wheel_speed, {limit} m/s ({self._info_source}): at most "
                             f"{limit / half_track:.2f} rad/s")
        return await self._closed_loop(f"turn({math.degrees(angle):.1f}°)", _Spin, angle * half_track,
                                       speed * half_track, timeout)

    async def _closed_loop(self, what: str, goal_type: type[_Straight], target: float, speed: float,
                           timeout: float | None) -> m.Pose:
        """Run the wheels until odometry says their rims went ``target`` m along the goal's pattern."""
        if timeout is None:
            timeout = 3 * abs(target) / speed + 5.0
        elif (timeout := _number("timeout", timeout)) <= 0:
            raise ValueError(f"timeout: must be > 0 s, got {timeout}")
        track = (await self.info()).track
        self._end_hold(f"{what} from this program")
        move = self._moving = _Move()
        self._moved = True
        latest = self._latest[keys.ODOM_POSE.name]
        fresh = asyncio.Event()
        goal: _Straight | None = None

        def done() -> str:
            return "nothing" if goal is None else goal.show(goal.progress(latest.value))

        def on_pose(_pose: m.Pose) -> None:
            fresh.set()

        async def next_pose() -> m.Pose:
            fresh.clear()
            try:
                await asyncio.wait_for(fresh.wait(), self.timeout)
            except TimeoutError:
                raise NotReachable(f"{what}: nothing on {self.node.key(keys.ODOM_POSE)} for {self.timeout} s "
                                   f"(is odometry running?); stopped") from None
            if move.cut is not None:
                raise MotionStopped(f"{what}: ended by {move.cut} after {done()}")
            if loop.time() > deadline:
                raise MotionTimeout(f"{what}: {done()} done after {timeout:.1f} s (timeout); stopped. "
                                    f"A wheel blocked, or a speed too low for the motors?")
            return latest.value

        async def run(goal: _Straight, direction: float, top: float) -> m.Pose:
            """Drive towards the target until the stop must go; stop; wait until at rest."""
            while True:
                pose = await next_pose()
                rest = direction * (target - goal.progress(pose))
                if rest <= goal.rim_speed(pose) * STOP_LAG_S:
                    break
                rim = direction * min(top, max(CREEP_SPEED, rest / SLOW_DOWN_S))
                steer = goal.steer(pose)
                self._wheels.put(self.command(m.WheelSpeeds, left=goal.wheels[0] * rim - steer,
                                              right=goal.wheels[1] * rim + steer))
            self._halt()
            stopped_at, speed_at = goal.progress(pose), goal.rim_speed(pose)
            for _ in range(int(2.0 / 0.02)):  # at rest within ~2 s (odometry comes at 50 Hz)
                pose = await next_pose()
                if abs(pose.v) < STILL_SPEED and abs(pose.w) < STILL_RATE:
                    break
            self.node.log.debug("%s: stop sent at %s, %s to go, rims at %.3f m/s; at rest after %s", what,
                                goal.show(stopped_at), goal.show(target - stopped_at), speed_at,
                                goal.show(goal.progress(pose)))
            return pose

        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        latest.callbacks.append(on_pose)
        try:
            with self._stop_unless_done():
                goal = goal_type(await next_pose(), track)
                tolerance = FORWARD_TOLERANCE if goal_type is _Straight else TURN_TOLERANCE * track / 2
                direction = math.copysign(1.0, target)
                pose = await run(goal, direction, speed)
                for _ in range(CORRECTIONS):
                    # Only a stop that came short: backing up at a crawl makes the PenguinPi's
                    # integral speed controller lurch further than most overshoots.
                    if direction * (target - goal.progress(pose)) <= tolerance:
                        break
                    pose = await run(goal, direction, CREEP_SPEED)
                return pose
        finally:
            latest.callbacks.remove(on_pose)
            if self._moving is move:
                self._moving = None

    async def led(self, led: int, on: bool = True, *, blink: float | tuple[float, float] | None = None,
                  times: int | None = None) -> None:
        """Switch LED ``led`` (1 red, 2..4 yellow) on or off (``io/leds``), or blink it.

        ``blink``: seconds lit and dark, one number for both or a pair ``(lit, dark)``, each at
        least 0.05 s; it blinks ``times`` times then stays dark, or (None) until this LED is set
        again or the client closes::

            await robot.led(2)                      # on
            await robot.led(3, blink=0.25)          # 2 Hz until further notice
            await robot.led(4, blink=(0.1, 0.9), times=5)
            await robot.led(3, False)               # off, and stops its blinking
        """
        led = self.leds._check(led)
        if blink is None:
            if times is not None:
                raise ValueError("times: only with blink")
            self.leds[led] = on
            return
        pair = tuple(blink) if isinstance(blink, tuple | list) else (blink, blink)
        if len(pair) != 2:
            raise ValueError(f"blink: one number of seconds, or two (lit, dark), got {blink!r}")
        lit, dark = _number("blink", pair[0]), _number("blink", pair[1])
        if min(lit, dark) < BLINK_MIN_S:
            raise ValueError(f"blink: each time must be >= {BLINK_MIN_S} s (the robot takes LED commands "
                             f"every 20 ms), got {blink!r}")
        if times is not None and (isinstance(times, bool) or not isinstance(times, int) or times < 1):
            raise ValueError(f"times: expected a whole number >= 1 (or None: for ever), got {times!r}")
        self._tasks = [task for task in self._tasks if not task.done()]  # ended blinks
        self._tasks.append(asyncio.create_task(self.leds.blink(led, lit, dark, times)))
        await asyncio.sleep(0)  # the blink has taken the LED when this returns

    async def print_oled(self, text: str) -> None:
        """Show ``text`` on the user screen (``oled/text``): ``\\n`` new line, ``\\f`` clear."""
        if not isinstance(text, str):
            raise ValueError(f"text: expected a string, got {text!r}")
        self._oled.put(m.OledText(text=text))

    def __repr__(self) -> str:
        return _describe(type(self).__name__, self)


def _describe(kind: str, robot: AsyncRobot) -> str:
    """``<Robot 'sim' at tcp/..: pose x=.. m y=.. m θ=..°, encoders L R, battery .. V>``."""
    parts = []
    if (p := robot.pose) is not None:
        parts.append(f"pose x={p.x:.3f} m y={p.y:.3f} m θ={math.degrees(p.theta):.1f}°")
    if (e := robot.encoders) is not None:
        parts.append(f"encoders L={e.left} R={e.right}")
    if (b := robot.battery) is not None:
        parts.append(f"battery {b.voltage:.2f} V")
    state = ", ".join(parts) or "no data yet"
    return f"<{kind} {robot.name!r} at {', '.join(robot.config.zenoh.connect)}: {state}>"


class Robot:
    """One robot on the bus, blocking calls: ``with Robot("sim") as robot: ...``.

    Same arguments and methods as `AsyncRobot`, but state properties (``pose``,
    ``encoders``, ``battery``, ``landmarks``, ``localized_pose``, ``dip``) wait up to
    ``timeout`` for the first message instead of returning None.

    Callbacks (``on_pose``, a button's ``when_pressed`` and ``when_released``) run one at a
    time, in order, on the robot's callback thread ``icefloe-callbacks``, not on yours: they may
    call the robot (``robot.buttons["S4"].when_pressed = robot.stop`` works), and while one runs
    the others wait, but the robot's state keeps coming in. An exception in a callback is
    logged (stderr and the robot's ``log`` key, with the callback's name), never lost, and the
    next event calls it again.

    Ctrl-C (KeyboardInterrupt) during a blocking motion (``forward``, ``turn``, timed
    ``set_velocity``/``drive``) stops the wheels before it reaches your code.
    """

    def __init__(self, name: str | None = None, *, connect: str | Sequence[str] | None = None,
                 config: str | Path | RobotConfig | None = None,
                 credentials: str | Path | None = None, timeout: float = 5.0) -> None:
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="icefloe-robot", daemon=True)
        self._thread.start()
        self._callbacks = ThreadPoolExecutor(max_workers=1, thread_name_prefix="icefloe-callbacks")
        self._pending: dict[Callable[..., object], int] = {}
        """Calls waiting on the callback thread, per callback (see `_dispatch`)."""
        self._pending_lock = threading.Lock()
        self._behind = LimitedLog(logging.getLogger("icefloe.client"), burst=1)
        self._robot: AsyncRobot | None = None
        try:
            self._robot = self._call(self._open(name, connect, config, credentials, timeout))
        except BaseException:
            self.close()
            raise
        self._robot._dispatch = self._dispatch

    async def _open(self, name: str | None, connect: str | Sequence[str] | None,
                    config: str | Path | RobotConfig | None, credentials: str | Path | None,
                    timeout: float) -> AsyncRobot:
        robot = AsyncRobot(name, connect=connect, config=config, credentials=credentials,
                           timeout=timeout)
        try:
            return await robot.open()
        except BaseException:
            await robot.close()
            raise

    def _call(self, coro: Coroutine[Any, Any, T]) -> T:
        if threading.current_thread() is self._thread:
            coro.close()
            raise RuntimeError("a blocking Robot method was called on the robot's event loop (from an "
                               "async callback?): use a plain function as the callback")
        future = asyncio.run_coroutine_threadsafe(coro, self._loop)
        try:
            return future.result()
        except IcefloeError as exc:
            # Raised again here, without the frames of the robot's own thread: the student's
            # traceback ends at their own call, with our message.
            raise type(exc)(*exc.args) from None
        except BaseException:
            future.cancel()  # Ctrl-C while waiting: the call ends in the loop too
            raise

    def _move(self, coro: Coroutine[Any, Any, T]) -> T:
        """A blocking motion: if the wait ends early (Ctrl-C), the wheels are stopped before we go on.
        (The motion's own errors have stopped them already; a bad argument sent nothing.)"""
        try:
            return self._call(coro)
        except Exception:
            raise
        except BaseException:
            with contextlib.suppress(Exception):
                self._call(self._r.stop())
            raise

    def _dispatch(self, callback: Callable[..., object], args: tuple[Any, ...]) -> None:
        """Run a user's callback on the callback thread (called in the loop, never blocks it).

        A callback slower than its events (an ``on_pose`` that takes 0.1 s, at 50 poses a second)
        has at most `MAX_PENDING_CALLS` calls waiting: the newer events are dropped, with a warning."""
        log = self._robot.node.log if self._robot is not None else logging.getLogger("icefloe.client")
        with self._pending_lock:
            waiting = self._pending.get(callback, 0)
            if waiting >= MAX_PENDING_CALLS:
                self._behind.warning("callback behind", "callback %r is %d events behind: newer ones dropped",
                                     callback, waiting)
                return
            self._pending[callback] = waiting + 1

        def run() -> None:
            with self._pending_lock:
                self._pending[callback] -= 1
                if not self._pending[callback]:
                    del self._pending[callback]
            try:
                callback(*args)
            except Exception as exc:
                if self._robot is not None:
                    self._robot.callback_failed(callback, exc)
                else:
                    log.exception("callback %r failed", callback)

        with contextlib.suppress(RuntimeError):  # closing: no more callbacks
            self._callbacks.submit(run)

    @property
    def _r(self) -> AsyncRobot:
        if self._robot is None:
            raise RuntimeError("robot is closed")
        return self._robot

    def _state(self, name: str, read: Callable[[AsyncRobot], T]) -> T:
        self._call(self._r.ready(name))
        return read(self._r)

    def close(self) -> None:
        """Stop the wheels if this program moved them, close the session and the thread."""
        if self._robot is not None:
            with contextlib.suppress(Exception):
                self._call(self._robot.close())
            self._robot = None
        if self._loop.is_running():
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join()
        if not self._loop.is_closed():
            self._loop.close()
        # No new callbacks start; one that is running may finish (the robot is closed for it).
        self._callbacks.shutdown(wait=False, cancel_futures=True)

    def __enter__(self) -> Robot:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @property
    def name(self) -> str:
        """The robot's name."""
        return self._r.name

    @property
    def leds(self) -> Leds:
        """The board's LEDs: ``robot.leds[2] = True``, ``robot.leds.pulse(3, 0.1)``."""
        return self._r.leds

    @property
    def pose(self) -> m.Pose:
        """Latest ``odom/pose``: x, y (m), theta (rad, CCW positive), v (m/s), w (rad/s)."""
        return self._state(keys.ODOM_POSE.name, lambda r: r.pose)

    @property
    def encoders(self) -> Encoders:
        """Latest encoder counts (left, right), unwrapped."""
        return self._state(keys.WHEELS.name, lambda r: r.encoders)

    @property
    def wheels(self) -> m.Wheels:
        """Latest ``hw/wheels``: counts, measured and commanded rim speeds (m/s)."""
        return self._state(keys.WHEELS.name, lambda r: r.wheels)

    @property
    def battery(self) -> m.BatteryReading:
        """Latest ``hw/battery``: voltage (V), current (A)."""
        return self._state(keys.HW_BATTERY.name, lambda r: r.battery)

    @property
    def landmarks(self) -> list[m.Landmark]:
        """Markers seen in the latest camera frame: id, range (m), bearing (rad, CCW positive)."""
        return self._state(keys.LANDMARKS.name, lambda r: r.landmarks)

    @property
    def localized_pose(self) -> m.PoseEstimate:
        """Latest ``loc/pose``: the localizer's x, y (m), theta (rad) in the map, with covariance."""
        return self._state(keys.LOC_POSE.name, lambda r: r.localized_pose)

    @property
    def external_pose(self) -> m.ExternalPose:
        """Latest ``extloc/pose``: the lab's overhead camera's x, y (m), theta (rad) in the world,
        with covariance (docs/extloc.md)."""
        return self._state(keys.EXTLOC_POSE.name, lambda r: r.external_pose)

    @property
    def slam_pose(self) -> m.PoseEstimate:
        """Latest ``slam/pose``: SLAM's pose in its own frame, with covariance (waits for the first)."""
        return self._state(keys.SLAM_POSE.name, lambda r: r.slam_pose)

    @property
    def slam_map(self) -> m.LandmarkMap:
        """Latest ``slam/map``: SLAM's landmarks with their covariances (waits for the first)."""
        return self._state(keys.SLAM_MAP.name, lambda r: r.slam_map)

    @property
    def landmark_map(self) -> m.LandmarkMap:
        """Latest ``map/landmarks``: the map maker's landmarks with covariances (waits for the first)."""
        return self._state(keys.MAP_LANDMARKS.name, lambda r: r.landmark_map)

    @property
    def dip(self) -> int:
        """The DIP switches, 0..15 (SW1 = 8, SW2 = 4, SW3 = 2, SW4 = 1), from ``io/dip``."""
        return self._state(keys.DIP.name, lambda r: r.dip)

    @property
    def buttons(self) -> Buttons:
        """The robot's buttons: ``robot.buttons["S4"].when_pressed = hello`` (see `Button`)."""
        return self._r.buttons

    def wait_for_press(self, button: int | str = "S4", timeout: float | None = None) -> bool:
        """Block until ``button`` (default S4) is pressed; False after ``timeout`` s without a press."""
        return self._call(self._r.wait_for_press(button, timeout))

    def info(self) -> m.RobotInfo:
        """What the robot is: board, wheel geometry, ``max_wheel_speed`` (see `AsyncRobot.info`)."""
        return self._call(self._r.info())

    def set_velocity(self, left: float, right: float, duration: float | None = None,
                     accel: float | None = None) -> m.MotionDone | None:
        """See `AsyncRobot.set_velocity` (m/s; with ``duration`` it blocks until the motion ends)."""
        return self._move(self._r.set_velocity(left, right, duration, accel))

    def drive(self, v: float, w: float, duration: float | None = None,
              accel: float | None = None) -> m.MotionDone | None:
        """Drive at ``v`` m/s turning at ``w`` rad/s (CCW); see `AsyncRobot.drive`::

            robot.drive(0.1, 0.5)     # a circle, until robot.stop()
        """
        return self._move(self._r.drive(v, w, duration, accel))

    def drive_car(self, v: float, steer: float, duration: float | None = None) -> None:
        """Drive as a car: ``v`` m/s, the front wheel at ``steer`` rad (left positive); held until the
        next command or `stop`, or for ``duration`` s and then stopped; see `AsyncRobot.drive_car`::

            robot.drive_car(0.2, 0.3)     # a 0.48 m circle to the left, until robot.stop()
        """
        self._move(self._r.drive_car(v, steer, duration))

    @contextlib.contextmanager
    def car(self, v: float = 0.0, steer: float = 0.0) -> Iterator[Robot]:
        """Drive as a car while the block runs; stopped (and confirmed) when it ends, however it
        ends (an exception, Ctrl-C); see `AsyncRobot.car`::

            with robot.car(0.2, 0.3):
                time.sleep(2.0)
                robot.drive_car(0.2, -0.3)
                time.sleep(2.0)
        """
        self.drive_car(v, steer)
        try:
            yield self
        finally:
            self._call(self._r.stop())

    @property
    def car_state(self) -> m.CarState:
        """Latest ``car/state`` (waits for the first): the virtual car's speed, steering and its
        bicycle-model pose; see `AsyncRobot.car_state`."""
        return self._state(keys.CAR_STATE.name, lambda r: r.car_state)

    def forward(self, distance: float, speed: float = 0.15, *, timeout: float | None = None) -> m.Pose:
        """Drive straight ``distance`` m (negative: back) by odometry, stop; see `AsyncRobot.forward`::

            robot.forward(0.3)
        """
        return self._move(self._r.forward(distance, speed, timeout=timeout))

    def turn(self, angle: float, speed: float = 1.0, *, timeout: float | None = None) -> m.Pose:
        """Turn on the spot by ``angle`` rad (CCW positive) by odometry, stop; see `AsyncRobot.turn`::

            robot.turn(math.radians(90))
        """
        return self._move(self._r.turn(angle, speed, timeout=timeout))

    def led(self, led: int, on: bool = True, *, blink: float | tuple[float, float] | None = None,
            times: int | None = None) -> None:
        """Switch LED ``led`` (1..4) on or off, or blink it; see `AsyncRobot.led`::

            robot.led(3, blink=0.25)
        """
        self._call(self._r.led(led, on, blink=blink, times=times))

    def stop(self, confirm: bool = True) -> m.Wheels | None:
        """Stop the wheels now; see `AsyncRobot.stop` (by default it returns once the robot
        confirmed the stop)."""
        return self._call(self._r.stop(confirm))

    def reset_pose(self, x: float = 0.0, y: float = 0.0, theta: float = 0.0) -> m.Pose:
        """Reset the odometry pose to x, y (m), theta (rad)."""
        return self._call(self._r.reset_pose(x, y, theta))

    def image(self, fresh: bool = False) -> np.ndarray:
        """The latest camera frame, BGR numpy array; ``fresh``: wait for the next one."""
        return self._call(self._r.image(fresh))

    def print_oled(self, text: str) -> None:
        """Show ``text`` on the user screen."""
        self._call(self._r.print_oled(text))

    def on_pose(self, callback: Callable[[m.Pose], object]) -> Callable[[], None]:
        """Call ``callback(pose)`` for every new pose (on the callback thread); returns a cancel function."""
        return self._r.on_pose(callback)

    def __repr__(self) -> str:
        return _describe("Robot", self._robot) if self._robot else "<Robot (closed)>"


__all__ = ["AsyncRobot", "Button", "Buttons", "Encoders", "Leds", "Robot"]
