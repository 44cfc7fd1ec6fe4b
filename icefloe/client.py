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
import inspect
import itertools
import math
import threading
import time
from collections.abc import Callable, Coroutine, Sequence
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import cv2
import msgspec
import numpy as np
import zenoh

from . import config as config_mod
from .config import RobotConfig
from .credentials import read as read_credentials
from .errors import BadPayload, ConfigError, NotConfirmed, NotReachable
from .runtime import Node, open_session
from .schemas import keys
from .schemas import messages as m
from .schemas.keys import Topic

T = TypeVar("T")
C = TypeVar("C", bound=m.Command)


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


class Leds:
    """The board's LEDs: ``robot.leds[2] = True`` publishes ``io/leds``.

    Reading ``robot.leds[2]`` gives what this client last set (the board does not
    report LED states on the bus).
    """

    def __init__(self, publish: Callable[[m.Led], None]) -> None:
        self._publish = publish
        self._state: dict[int, bool] = {}

    def _check(self, led: object) -> int:
        if isinstance(led, bool) or not isinstance(led, int) or not 1 <= led <= 4:
            raise ValueError(f"led: expected 1 (red) or 2..4 (yellow), got {led!r}")
        return led

    def __getitem__(self, led: int) -> bool:
        return self._state.get(self._check(led), False)

    def __setitem__(self, led: int, on: bool) -> None:
        led = self._check(led)
        self._publish(m.Led(led=led, on=bool(on)))
        self._state[led] = bool(on)

    def pulse(self, led: int, seconds: float) -> None:
        """Light ``led`` for ``seconds`` (0 < seconds <= 0.255 on the PenguinPi), then off."""
        led = self._check(led)
        seconds = _number("seconds", seconds)
        if not 0 < seconds <= 0.255:
            raise ValueError(f"seconds: must be in (0, 0.255], got {seconds}")
        self._publish(m.Led(led=led, on=True, pulse=seconds))

    def __repr__(self) -> str:
        return f"Leds({self._state})"


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
                 service: str = "client") -> None:
        try:
            self.config = _config(name, connect, config, credentials)
        except ConfigError as exc:
            raise ValueError(f"config: {exc}") from None
        self.name = self.config.name
        self.timeout = _number("timeout", timeout)
        self.node = Node(service, self.config)
        self._latest = {t.name: _Latest(t) for t in
                        (keys.ODOM_POSE, keys.WHEELS, keys.HW_BATTERY, keys.LANDMARKS, keys.IMAGE)}
        self._tasks: list[asyncio.Task[None]] = []
        self._hold: asyncio.Task[None] | None = None
        self._moved = False
        self._stop_sub: Any = None
        self.leds: Leds
        self._sender = ""
        self._seq = itertools.count(1)
        # `stamp` comes from a clock that never jumps back (the wall clock read once, then
        # advanced by the monotonic clock): hwbridge learns its offset from the robot's.
        self._wall0, self._mono0 = time.time_ns(), time.monotonic_ns()

    # ------------------------------------------------------------------ connection

    async def open(self, connect_timeout: float | None = None) -> AsyncRobot:
        """Connect to the robot's router; `NotReachable` naming the endpoint after
        ``connect_timeout`` s (default: ``timeout``; ``math.inf``: wait for good, as a service does).
        """
        endpoints = ", ".join(self.config.zenoh.connect)
        connect_timeout = self.timeout if connect_timeout is None else connect_timeout
        deadline = time.monotonic() + connect_timeout
        while True:  # the router may be starting (robot just booted): retry until the deadline
            try:
                probe = await open_session(self.config, retry=False)
                probe.close()
                break
            except NotReachable:
                if time.monotonic() > deadline:
                    raise NotReachable(f"robot {self.name!r}: no Zenoh router answers at {endpoints} "
                                       f"within {connect_timeout} s") from None
                await asyncio.sleep(0.2)
        await self.node.__aenter__()  # the router answers: this opens at once
        self._sender = str(self.node.session.zid())
        self._wheels = self.node.publisher(keys.WHEELS_CMD)
        self._stop = self.node.publisher(keys.STOP)
        self._oled = self.node.publisher(keys.OLED_TEXT)
        self.leds = Leds(self.node.publisher(keys.LEDS).put)
        for name in self._latest:
            if name != keys.IMAGE.name:  # images are big: only once someone asks for one
                self._follow(name)
        # Somebody else's stop (a tool, another program) must end our held velocity.
        # Our own stops come back to us too; REMOTE ignores them.
        loop = asyncio.get_running_loop()

        def on_stop(_sample: zenoh.Sample) -> None:  # Zenoh thread: hand over to the loop
            with contextlib.suppress(RuntimeError):  # the loop is closing
                loop.call_soon_threadsafe(self._end_hold)

        self._stop_sub = self.node.session.declare_subscriber(
            self.node.key(keys.STOP), on_stop, allowed_origin=zenoh.Locality.REMOTE)
        return self

    async def close(self) -> None:
        """Stop the wheels if this client moved them, and close the session."""
        if self._moved and hasattr(self, "_stop"):
            self._end_hold()
            self._stop.put(self.command(m.Stop))
        for task in self._tasks:
            task.cancel()
        self._end_hold()
        if self._stop_sub is not None:
            self._stop_sub.undeclare()
            self._stop_sub = None
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
                except Exception:  # a student's callback must not end the subscription
                    self.node.log.exception("callback %r failed", callback)

    async def ready(self, *names: str, timeout: float | None = None) -> None:
        """Wait until ``names`` ("odom/pose", "hw/wheels", ...) have each sent a first message."""
        for name in names or tuple(self._latest):
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
        callbacks.append(callback)
        return lambda: callbacks.remove(callback) if callback in callbacks else None

    # ------------------------------------------------------------------ commands

    def command(self, kind: type[C], **fields: Any) -> C:
        """A command message of type ``kind`` (`m.Twist`, `m.Stop`, ...) with ``fields``, numbered
        and stamped as this client's next command. For publishing a command yourself."""
        stamp = self._wall0 + time.monotonic_ns() - self._mono0
        return kind(sender=self._sender, seq=next(self._seq), stamp=stamp, **fields)

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
        return await self.node.query(keys.MOTION, motion, timeout=duration + accel + self.timeout)

    async def _hold_speeds(self, left: float, right: float) -> None:
        period = self.config.hwbridge.deadman_s / 4
        while True:
            self._wheels.put(self.command(m.WheelSpeeds, left=left, right=right))
            await asyncio.sleep(period)

    def _end_hold(self) -> None:
        if self._hold is not None:
            self._hold.cancel()
            self._hold = None

    async def stop(self, confirm: bool = True) -> m.Wheels | None:
        """Stop the wheels now (``cmd/stop``); also ends a held velocity or a timed motion.

        With ``confirm`` (the default) it then asks hwbridge (``cmd/halt`` with ``rest =
        False``, the same stop) and returns once the board runs zero duty with its
        controller cleared, with the wheel state at that moment; `NotConfirmed` if
        hwbridge could not confirm it, `NotReachable` if hwbridge does not answer.
        """
        self._end_hold()
        stop = self.command(m.Stop)
        self._stop.put(stop)
        if not confirm:
            return None
        halt = m.Halt(sender=stop.sender, seq=stop.seq, stamp=stop.stamp, rest=False)
        try:
            return await self.node.query(keys.HALT, halt, timeout=self.timeout)
        except BadPayload as exc:  # hwbridge's answer: why it could not confirm
            raise NotConfirmed(str(exc)) from None

    async def reset_pose(self, x: float = 0.0, y: float = 0.0, theta: float = 0.0) -> m.Pose:
        """Reset the odometry pose (``odom/reset`` query) to x, y (m), theta (rad); returns it."""
        request = m.PoseReset(x=_number("x", x), y=_number("y", y), theta=_number("theta", theta))
        return await self.node.query(keys.ODOM_RESET, request, timeout=self.timeout)

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
    ``encoders``, ``battery``, ``landmarks``) wait up to ``timeout`` for the
    first message instead of returning None. Callbacks (``on_pose``) run on the
    robot's own thread: keep them short.
    """

    def __init__(self, name: str | None = None, *, connect: str | Sequence[str] | None = None,
                 config: str | Path | RobotConfig | None = None,
                 credentials: str | Path | None = None, timeout: float = 5.0) -> None:
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="icefloe-robot", daemon=True)
        self._thread.start()
        self._robot: AsyncRobot | None = None
        try:
            self._robot = self._call(self._open(name, connect, config, credentials, timeout))
        except BaseException:
            self.close()
            raise

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
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result()

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

    def set_velocity(self, left: float, right: float, duration: float | None = None,
                     accel: float | None = None) -> m.MotionDone | None:
        """See `AsyncRobot.set_velocity` (m/s; with ``duration`` it blocks until the motion ends)."""
        return self._call(self._r.set_velocity(left, right, duration, accel))

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
        """Call ``callback(pose)`` for every new pose (on the robot's thread); returns a cancel function."""
        return self._r.on_pose(callback)

    def __repr__(self) -> str:
        return _describe("Robot", self._robot) if self._robot else "<Robot (closed)>"


__all__ = ["AsyncRobot", "Encoders", "Leds", "Robot"]
