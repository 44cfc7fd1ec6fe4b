"""The HTTP routes of the PenguinPi web API, each turned into bus messages.

Every handler first parses all its parameters (`params`), so a rejected request
sends nothing. Bodies and content types are the old server's (facts §5.2):
text as ``text/html; charset=utf-8`` (MATLAB's PiBot decodes the JSON itself and
would choke on ``application/json``), errors as ``{"message": ...}`` with
status 400. When the robot's service behind a route does not answer, the route
answers 503 with a message naming the bus key.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sys
from collections.abc import Awaitable, Callable
from typing import Any

import zenoh
from aiohttp import web
from aiohttp.http_exceptions import HttpProcessingError

from icefloe.client import AsyncRobot
from icefloe.credentials import GUEST_USER
from icefloe.errors import BadPayload, NotConfirmed, NotReachable
from icefloe.logs import LimitedLog, printable
from icefloe.router import access_control, permits
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m

from . import params, timing
from .auth import Login, owner_only
from .bus import Bridge, Caller, HttpError, render
from .camera import Camera
from .fanout import Hub
from .pages import Pages
from .params import InvalidCommand
from .state import State

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]

LOG_HISTORY = 50
"""Log lines a new stream of ``log`` starts with (the robot's page shows them)."""
S4 = 3
"""io/buttons number of the HAT's S4, the button the old /hat/button/get counted."""


def text(body: object = "") -> web.Response:
    """A plain reply as Flask sends a ``str``: 200, text/html; charset=utf-8."""
    return web.Response(text=str(body), content_type="text/html", charset="utf-8")


def error(status: int, message: str) -> web.Response:
    """``{"message": ...}`` as application/json (no charset, as Flask's jsonify)."""
    return web.Response(status=status, body=json.dumps({"message": message}).encode(),
                        content_type="application/json")


LIMITED = web.AppKey("limited", LimitedLog)
"""The app's log for refused requests (a few lines per second per route)."""


@web.middleware
async def errors(request: web.Request, handler: Handler) -> web.StreamResponse:
    """Turn refusals into the old server's 400 JSON, silent services into 503, and an answer
    that is an error or cannot be read into 502 (each a JSON message naming the key)."""
    try:
        return await handler(request)
    except InvalidCommand as exc:
        route = request.match_info.route.resource
        request.app[LIMITED].info(route.canonical if route else "?", "%s rejected: %s", request.rel_url, exc.message)
        return error(400, exc.message)
    except NotReachable as exc:
        request.app[LIMITED].warning("not reachable", "%s: %s", request.rel_url, exc)
        return error(503, f"robot not answering: {exc}")
    except NotConfirmed as exc:
        request.app[LIMITED].warning("not confirmed", "%s: %s", request.rel_url, exc)
        return error(503, f"stop not confirmed: {exc}")
    except BadPayload as exc:  # whatever answered the query said no, or said something unreadable
        request.app[LIMITED].warning("bad answer", "%s: %s", request.rel_url, exc)
        return error(502, f"bad answer from the robot: {exc}")


class ServerLog(logging.LoggerAdapter):
    """aiohttp's server log for webapi (``AppRunner(logger=...)``).

    aiohttp answers a request it cannot parse (a line longer than 8190 bytes, a bad method,
    garbage, a bad header) with 400 and closes the connection; then it logs an ERROR with a
    traceback, once per request. Here that becomes one short line, a few per second (`LimitedLog`).
    Any other error (a bug) keeps its traceback, rate-limited too.
    """

    def __init__(self, limited: LimitedLog) -> None:
        super().__init__(logging.getLogger("aiohttp.server"), {})
        self.limited = limited

    def _bad_request(self, args: tuple[object, ...], exc: object) -> bool:
        if not isinstance(exc, HttpProcessingError):
            return False
        remote = f" from {args[0]}" if args else ""  # aiohttp: "Error handling request from %s", remote
        what = exc.message.split("\n", 1)[0].strip(" :")  # the rest quotes the request
        self.limited.warning("bad HTTP request", "bad HTTP request%s, answered %d: %s: %s", remote,
                             exc.code or 400, type(exc).__name__, printable(what, 80))
        return True

    def exception(self, msg: object, *args: object, exc_info: Any = True, **kwargs: Any) -> None:
        exc = exc_info if isinstance(exc_info, BaseException) else sys.exc_info()[1]
        if not self._bad_request(args, exc):
            self.limited.error("HTTP server error", str(msg), *args, exc_info=exc)

    def debug(self, msg: object, *args: object, **kwargs: Any) -> None:
        if not self._bad_request(args, kwargs.get("exc_info")):
            super().debug(msg, *args, **kwargs)


class Api:
    """The state the routes share: the robot on the bus and the PenguinPi extras."""

    def __init__(self, robot: AsyncRobot, guest: zenoh.Session | None = None) -> None:
        self.robot = robot
        self.node: Node = robot.node
        config = robot.config
        self.unit = params.demand_to_mps(config.geometry)
        """m/s per firmware demand unit."""
        self.max_demand = config.webapi.max_demand
        self.max_time = config.webapi.max_time
        self.signs = config.webapi.wheel_signs
        """(left, right): how the old API's clients see each wheel (``[webapi] wheel_signs``): their
        demands and counts of a wheel with -1 are negated on the way in and out."""
        self.demand = [0.0, 0.0]
        """Last held demands (left, right), for /motor/set/velocity."""
        self.encoder_zero = (0, 0)
        """Counts at the last /robot/hw/reset; the bus counts never reset."""
        self.s4_presses = 0
        self.follows = State(self.node)
        """hw/wheels, odom/pose, hw/battery, io/dip: followed only while routes read them (`state`)."""
        self.camera = Camera(self.node, robot.timeout, single=config.webapi.camera_get == "frame")
        """/camera/get (the MJPEG stream, or one JPEG), /camera/frame, /camera/info (`camera`)."""
        self._text = self.node.publisher(keys.BOARD_TEXT)
        self._screen = self.node.publisher(keys.BOARD_SCREEN)
        self._ledarray = self.node.publisher(keys.LEDARRAY)
        self._leds = self.node.publisher(keys.LEDS)
        zenoh = config.zenoh
        self.login = (Login(zenoh.user, zenoh.password, robot.name, self.node.limited)
                      if zenoh.access_control else None)
        """The owner's login on a robot with access control (`auth`), else None: anyone may do anything."""
        self._callers: dict[str, Caller] = {}
        """Who HTTP bridge requests act as, by Zenoh user: each with a session logged in as that
        user, so the robot's router checks what they do too; the owner's is the service's own."""
        for user, session in ((zenoh.user, self.node.session), (GUEST_USER, guest)):
            if session is not None:
                self._callers[user] = Caller(user, session, Hub(session, render))
                # The page shows the last lines of the log.
                self._callers[user].hub.pin(self.node.key(keys.LOG), history=LOG_HISTORY)
        self.acl = access_control([(robot.name, zenoh.user)]) if self.login is not None else None
        """Zenoh's rules, as the robot's router has them (`icefloe.router.access_control`)."""
        self.bridge = Bridge(robot.name, self.caller, self.allowed, self.order, query_timeout=robot.timeout)
        self.pages = Pages(self)

    def caller(self, request: web.Request) -> Caller:
        """Who an HTTP bridge request is from: on a robot with access control the user it logs in
        as (no login: the guest), 401 for a wrong login; on a robot without, anyone."""
        if self.login is None:
            return self._callers[self.robot.config.zenoh.user]
        user = self.login.user_of(request)
        if user is None:
            raise HttpError(401, f"wrong user or password for robot {self.robot.name}", self.login.challenge)
        if "Authorization" not in request.headers:
            return dataclasses.replace(self._callers[user], challenge=self.login.challenge)
        return self._callers[user]

    def order(self, message: m.Message) -> m.Message:
        """A command the HTTP client did not number (no ``sender``) is numbered as the web API's
        next one, so hwbridge puts it and the stops around it in the order they came in here."""
        if isinstance(message, m.Command) and not message.sender:
            given = {f: getattr(message, f) for f in message.__struct_fields__ if f not in ("sender", "seq", "stamp")}
            return self.node.command(type(message), **given)
        return message

    def allowed(self, who: Caller, message: str, key_expr: str) -> bool:
        """Zenoh's decision for ``who`` sending ``message`` on ``key_expr`` (`icefloe.router.permits`)."""
        return self.acl is None or permits(self.acl, who.user, message, key_expr)

    async def follow(self) -> None:
        """Count S4 presses (run as a task): every press counts, so this one is followed for good
        (it costs nothing while nobody presses)."""
        await self._follow_buttons()

    async def _follow_buttons(self) -> None:
        async for press in self.node.subscribe(keys.BUTTONS, latest=False):  # count every one
            if press.button == S4:
                self.s4_presses += press.presses

    # ------------------------------------------------------------------ helpers

    async def counts(self) -> m.Wheels | None:
        """The newest ``hw/wheels`` (after a pause, the first within the bus timeout), or None."""
        return await self.follows.get(keys.WHEELS, self.robot.timeout)

    async def encoders(self) -> tuple[int, int] | None:
        """Counts since the last /robot/hw/reset, wrapped to int16 as the firmware's, each with
        its wheel's sign (``[webapi] wheel_signs``)."""
        counts = await self.counts()
        if counts is None:
            return None
        return (params.to_int16(self.signs[0] * (counts.ticks_left - self.encoder_zero[0])),
                params.to_int16(self.signs[1] * (counts.ticks_right - self.encoder_zero[1])))

    async def get_dip(self) -> int | None:
        """The DIP switch (hwbridge sends it once a second), or None if none came within the bus timeout."""
        dip = await self.follows.get(keys.DIP, self.robot.timeout)
        return None if dip is None else dip.value

    async def state(self) -> web.Response:
        """The state JSON of §5.5, in the old pose convention (y right, theta clockwise)."""
        self.follows.follow(keys.WHEELS, keys.ODOM_POSE)
        left, right = await self.encoders() or (None, None)  # null before hwbridge's first counts
        pose = await self.follows.get(keys.ODOM_POSE, self.robot.timeout)
        body = {
            "encoder": {"left": left, "right": right},
            # Before the first pose the old server had integer zeros; so do we.
            "pose": {"x": 0, "y": 0, "theta": 0} if pose is None else
                    {"x": pose.x, "y": -pose.y, "theta": -pose.theta},
        }
        return text(json.dumps(body))

    async def drive(self, left: float, right: float) -> None:
        """Hold wheel demands (firmware units, as the client sees the wheels) until the next command."""
        self.demand = [left, right]
        await self.robot.set_velocity(*self.speeds(left, right))

    def speeds(self, left: float, right: float) -> tuple[float, float]:
        """A client's demands (firmware units) -> the wheels' rim speeds on the bus (m/s), each
        with its wheel's sign (``[webapi] wheel_signs``)."""
        return left * self.signs[0] * self.unit, right * self.signs[1] * self.unit

    # ------------------------------------------------------------------ robot

    async def set_velocity(self, request: web.Request) -> web.Response:
        left, right = params.speeds(request.query, self.max_demand)
        duration, accel = params.timing(request.query, self.max_time)
        self.follows.follow(keys.WHEELS, keys.ODOM_POSE)  # the answer's state: subscribed meanwhile
        if duration is None:
            await self.drive(left, right)
        else:
            # One cmd/motion query: hwbridge ramps, holds and stops, and answers when done.
            self.demand = [0.0, 0.0]
            await self.robot.set_velocity(*self.speeds(left, right),
                                          self.timed_duration(left, right, duration, accel), accel)
        return await self.state()

    def timed_duration(self, left: float, right: float, duration: float, accel: float) -> float:
        """How long hwbridge holds a timed motion so that it covers V·T (`timing.timed_duration`)."""
        hw = self.robot.config.hwbridge
        return timing.timed_duration(left, right, duration, accel, unit=self.unit,
                                     max_speed=hw.max_wheel_speed, max_accel=hw.max_accel)

    async def stop(self, request: web.Request) -> web.Response:
        """Answers once hwbridge has confirmed the stop: the board runs zero duty."""
        self.follows.follow(keys.WHEELS, keys.ODOM_POSE)
        self.demand = [0.0, 0.0]
        await self.robot.stop()
        return await self.state()

    async def get_encoder(self, request: web.Request) -> web.Response:
        enc = await self.encoders()
        if enc is None:
            raise NotReachable(f"no encoder counts yet on {self.node.key(keys.WHEELS)}")
        return text(f"{enc[0]},{enc[1]}")

    async def hw_reset(self, request: web.Request) -> web.Response:
        # The old MULTI_CLEAR_DATA stopped the motors and zeroed the counters.
        await self.stop(request)
        counts = await self.counts()
        if counts is not None:
            self.encoder_zero = (counts.ticks_left, counts.ticks_right)
        return text()

    async def pose_reset(self, request: web.Request) -> web.Response:
        await self.robot.reset_pose()
        return text()

    # ------------------------------------------------------------------ motors

    async def motor_encoder(self, request: web.Request) -> web.Response:
        side = params.integer(request.query, "id", "Bad motor id", 0, 1)
        enc = await self.encoders()
        if enc is None:
            raise NotReachable(f"no encoder counts yet on {self.node.key(keys.WHEELS)}")
        return text(enc[side])

    async def motor_velocity(self, request: web.Request) -> web.Response:
        side = params.integer(request.query, "id", "Bad motor id", 0, 1)
        value = params.integer(request.query, "value", "Bad motor value",
                               -self.max_demand, self.max_demand)
        demand = list(self.demand)
        demand[side] = value
        await self.drive(*demand)
        return text()

    # ------------------------------------------------------------------ battery

    async def battery(self) -> m.BatteryReading:
        reading = await self.follows.get(keys.HW_BATTERY, self.robot.timeout)
        if reading is None:
            raise NotReachable(f"nothing on {self.node.key(keys.HW_BATTERY)} within {self.robot.timeout} s "
                               "(is the service running?)")
        return reading

    async def voltage(self, request: web.Request) -> web.Response:
        return text(float(round((await self.battery()).voltage * 1000, 3)))  # mV, as str(float)

    async def current(self, request: web.Request) -> web.Response:
        return text(float(round((await self.battery()).current * 1000, 3)))  # mA

    # ------------------------------------------------------------------ HAT

    async def dip_get(self, request: web.Request) -> web.Response:
        dip = await self.get_dip()
        if dip is None:
            raise NotReachable(f"no DIP switch reading yet on {self.node.key(keys.DIP)}")
        return text(dip)

    async def button_get(self, request: web.Request) -> web.Response:
        count, self.s4_presses = self.s4_presses, 0  # read resets, as HAT_GET_BUTTON did
        return text(count)

    async def ledarray_set(self, request: web.Request) -> web.Response:
        mask = params.integer(request.query, "value", "Bad value", 0, 0xFFFF, any_base=True)
        self._ledarray.put(m.LedArray(mask=mask))
        return text()

    async def screen_set(self, request: web.Request) -> web.Response:
        index = params.integer(request.query, "value", "Bad screen value", 0, 255)
        self._screen.put(m.OledScreen(index=index))
        return text()

    async def screen_print(self, request: web.Request) -> web.Response:
        value = params.text(request.query)
        self._text.put(m.OledText(text=value))  # raw user text, no newline added
        self._screen.put(m.OledScreen(index=1))  # then show the USER screen
        return text()

    # ------------------------------------------------------------------ LEDs

    async def led_state(self, request: web.Request) -> web.Response:
        led = params.integer(request.query, "id", "Bad led id", 2, 4, any_base=True)
        on = params.integer(request.query, "value", "Bad led value", 0, 1)
        self.robot.leds[led] = bool(on)
        return text()

    async def led_count(self, request: web.Request) -> web.Response:
        led = params.integer(request.query, "id", "Bad led id", 2, 4, any_base=True)
        ms = params.integer(request.query, "value", "Bad led value", 0, 255, decimals=True)
        # Count 0 kept the LED on for good on the old board; pulse 0 means the same on the bus.
        self._leds.put(m.Led(led=led, on=True, pulse=ms / 1000))
        return text()

    def commands(self) -> dict[str, Handler]:
        """Routes that change something on the robot (or, for the button, reset a count):
        only the robot's owner may call them when the robot has access control (`auth`)."""
        return {
            "/robot/set/velocity": self.set_velocity,
            "/robot/stop": self.stop,
            "/robot/hw/reset": self.hw_reset,
            "/robot/pose/reset": self.pose_reset,
            "/motor/set/velocity": self.motor_velocity,
            "/hat/button/get": self.button_get,  # reading resets the count: a guest would eat the presses
            "/hat/ledarray/set": self.ledarray_set,
            "/hat/screen/set": self.screen_set,
            "/hat/screen/print": self.screen_print,
            "/led/set/state": self.led_state,
            "/led/set/count": self.led_count,
        }

    def reads(self) -> dict[str, Handler]:
        """Routes that only read: open to anyone, as the robot's state is to Zenoh's guest."""
        return {
            "/robot/get/encoder": self.get_encoder,
            "/motor/get/encoder": self.motor_encoder,
            "/battery/get/voltage": self.voltage,
            "/battery/get/current": self.current,
            "/hat/dip/get": self.dip_get,
            "/camera/get": self.camera.get,  # the MJPEG stream, or one JPEG ([webapi] camera_get)
            "/camera/frame": self.camera.frame,  # one JPEG, always
            "/camera/info": self.camera.info,  # the intrinsics of those JPEGs
        }

    def app(self) -> web.Application:
        """The routes; with access control, the commands need the robot's own user and password,
        and the HTTP bridge asks Zenoh's rules for the user a request logs in as."""
        middlewares = [errors]
        if self.login is not None:
            commands, forms = set(self.commands()), self.pages.commands()
            middlewares.append(owner_only(
                lambda r: r.path in commands or (r.method == "POST" and r.path in forms), self.login))
        app = web.Application(middlewares=middlewares)
        app[LIMITED] = self.node.limited
        for path, handler in {**self.commands(), **self.reads()}.items():
            app.router.add_get(path, handler)
        self.bridge.routes(app)
        self.pages.routes(app)
        app.on_shutdown.append(self._end_streams)
        return app

    async def _end_streams(self, app: web.Application) -> None:
        self.camera.close()
        self.follows.close()
        await self.bridge.close()
        for caller in self._callers.values():
            caller.hub.close()
