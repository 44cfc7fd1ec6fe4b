"""Shared parts of the web API tests: the webapi process, an HTTP client, a stand-in robot.

`Board` plays hwbridge, odometry and the camera from an in-process Node, so the
route tests can set exact encoder counts, battery readings and frames, and see
every command the web API sends. `tests/test_webapi_sim.py` runs the same
routes against the real simulator processes.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import time
from dataclasses import dataclass, field
from typing import Any

import aiohttp
import cv2
import msgspec
import numpy as np
from conftest import SIM_CONFIG, Proc, Robot, free_port, wait_for

from icefloe import config as config_mod
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m

TEXT = "text/html; charset=utf-8"
_GEOMETRY = config_mod.load(SIM_CONFIG).geometry
K = 10 * math.pi * _GEOMETRY.wheel_diameter / _GEOMETRY.ticks_per_rev
"""m/s per firmware demand unit of the test robots: 10 counts/s of the wheels sim.toml believes (its
calibrated [geometry], not the drawing's 65 mm)."""


def webapi_robot(make_robot: Any, extra: str = "") -> Robot:
    """A test robot whose web API listens on a free local port."""
    return make_robot(f'{extra}\n[webapi]\nhost = "127.0.0.1"\nport = {free_port()}\n')


@dataclass
class Http:
    """A plain HTTP client on the web API of one test robot."""

    base: str
    session: aiohttp.ClientSession
    proc: Proc
    """The webapi process."""

    async def get(self, path: str, **params: Any) -> tuple[int, str, str]:
        """GET ``path``; returns (status, content type header, body text)."""
        async with self.session.get(self.base + path, params=params or None) as r:
            body = await r.text()
            # 500 is an exception webapi did not turn into an answer: a bug, whatever the test expects.
            assert r.status != 500, f"GET {path} {params}: 500\n{self.proc.output[-4000:]}"
            return r.status, r.headers.get("Content-Type", ""), body

    async def send(self, method: str, path: str, body: bytes | str | None = None,
                   **params: Any) -> tuple[int, Any]:
        """``method`` ``path`` with ``body``; returns (status, the JSON answer)."""
        async with self.session.request(method, self.base + path, data=body, params=params or None) as r:
            text = await r.text()
            assert r.status != 500, f"{method} {path} {params}: 500\n{self.proc.output[-4000:]}"
            return r.status, json.loads(text) if text else None

    async def events(self, path: str, count: int, timeout: float = 20.0, **params: Any) -> list[tuple[str, Any]]:
        """The first ``count`` Server-Sent Events of ``path``: (event name, JSON data)."""
        found: list[tuple[str, Any]] = []
        async with self.session.get(self.base + path, params=params or None,
                                    headers={"Accept": "text/event-stream"}) as r:
            assert r.status == 200, await r.text()
            assert r.headers["Content-Type"] == "text/event-stream"
            async with asyncio.timeout(timeout):
                async for name, data in sse_events(r.content):
                    found.append((name, data))
                    if len(found) >= count:
                        break
        return found

    async def raw(self, path_and_query: str) -> tuple[int, str, str]:
        """GET a URL exactly as written (no encoding by the client, like pibot_client's printfOLED)."""
        url = aiohttp.client.URL(self.base + path_and_query, encoded=True)
        async with self.session.get(url) as r:
            return r.status, r.headers.get("Content-Type", ""), await r.text()


async def sse_events(stream: aiohttp.StreamReader) -> Any:
    """(event, JSON data) of each Server-Sent Event in an HTTP body (comments skipped)."""
    name, data = "message", []
    async for line in stream:
        text = line.decode().rstrip("\r\n")
        if not text:
            if data:
                joined = "\n".join(data)
                yield name, json.loads(joined) if joined[:1] in "[{" else joined
            name, data = "message", []
        elif text.startswith("event:"):
            name = text[6:].strip()
        elif text.startswith("data:"):
            data.append(text[5:].strip())


@contextlib.asynccontextmanager
async def webapi(robot: Robot) -> Any:
    """Start the webapi process and yield an `Http` client once it answers."""
    proc = robot.start("webapi")
    base = f"http://127.0.0.1:{robot.config.webapi.port}"
    async with aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=30)) as session:
        http = Http(base, session, proc)

        async def up() -> bool:
            assert proc.alive(), proc.output
            try:
                await http.get("/hat/button/get")
                return True
            except aiohttp.ClientConnectionError:
                return False

        deadline = time.monotonic() + 20
        while not await up():
            assert time.monotonic() < deadline, f"webapi did not answer:\n{proc.output}"
            await asyncio.sleep(0.1)
        yield http
    assert proc.stop() == 0, proc.output


def jpeg(width: int = 320, height: int = 240, shade: int = 0) -> bytes:
    """A real JPEG: a grey picture with a white square whose place depends on ``shade``."""
    img = np.full((height, width, 3), 60, np.uint8)
    x = 20 + shade % (width - 60)
    img[40:80, x:x + 40] = 255
    ok, data = cv2.imencode(".jpg", img)
    assert ok
    return data.tobytes()


@dataclass
class Board:
    """Plays hwbridge + odometry + camera on the bus, and records what it is told."""

    node: Node
    ticks: list[int] = field(default_factory=lambda: [0, 0])
    pose: m.Pose = field(default_factory=lambda: m.Pose(stamp=0, x=0.0, y=0.0, theta=0.0))
    battery: m.BatteryReading | None = None
    image: bytes | None = None
    wheels: list[m.WheelSpeeds] = field(default_factory=list)
    stops: list[m.Stop] = field(default_factory=list)
    halts: list[m.Halt] = field(default_factory=list)
    motions: list[m.Motion] = field(default_factory=list)
    motion_done_at: list[float] = field(default_factory=list)
    resets: list[m.PoseReset] = field(default_factory=list)
    raw: list[str] = field(default_factory=list)
    """Keys of every command sample the web API sent (cmd/**, io/**, oled/**)."""
    ready: asyncio.Event = field(default_factory=asyncio.Event)
    """Set once every subscriber and queryable is declared."""

    async def run(self) -> None:
        n = self.node
        wheels = n.publisher(keys.WHEELS)
        pose = n.publisher(keys.ODOM_POSE)
        battery = n.publisher(keys.HW_BATTERY)
        image = n.publisher(keys.IMAGE)

        async def motion(request: m.Motion) -> m.MotionDone:
            self.motions.append(request)
            await asyncio.sleep(request.duration + request.accel)
            self.motion_done_at.append(time.monotonic())
            return m.MotionDone(stamp=time.time_ns(), completed=True)

        async def reset(request: m.PoseReset) -> m.Pose:
            self.resets.append(request)
            self.pose = m.Pose(stamp=time.time_ns(), x=request.x, y=request.y, theta=request.theta)
            return self.pose

        async def halt(request: m.Halt) -> m.Wheels:  # hwbridge confirms a stop: at once here
            self.halts.append(request)
            return m.Wheels(stamp=time.time_ns(), ticks_left=self.ticks[0], ticks_right=self.ticks[1],
                            speed_left=0.0, speed_right=0.0)

        n.queryable(keys.MOTION, motion)
        n.queryable(keys.HALT, halt)
        n.queryable(keys.ODOM_RESET, reset)

        async def record(topic: keys.Topic, into: list[Any]) -> None:
            async for msg in n.subscribe(topic, latest=False):
                into.append(msg)

        async def record_raw(pattern: str) -> None:
            async for sample in n.subscribe_raw(n.key(pattern)):
                self.raw.append(keys.split(sample.key)[1])

        async def publish() -> None:
            while True:
                now = time.time_ns()
                wheels.put(m.Wheels(stamp=now, ticks_left=self.ticks[0], ticks_right=self.ticks[1],
                                    speed_left=0.0, speed_right=0.0))
                pose.put(msgspec.structs.replace(self.pose, stamp=now))
                if self.battery is not None:
                    battery.put(self.battery)
                if self.image is not None:
                    image.put(m.Image(stamp=now, width=320, height=240, data=self.image))
                await asyncio.sleep(0.05)

        async with asyncio.TaskGroup() as tg:
            tg.create_task(record(keys.WHEELS_CMD, self.wheels))
            tg.create_task(record(keys.STOP, self.stops))
            for pattern in ("cmd/**", "io/**", "oled/**"):
                tg.create_task(record_raw(pattern))
            tg.create_task(publish())
            await asyncio.sleep(0)  # the tasks above have run up to their first wait: declared
            # Declarations reach the router asynchronously; give them a moment, as a
            # service that just started would have had.
            await asyncio.sleep(0.3)
            self.ready.set()


async def sim_state(node: Node) -> m.SimState:
    """The simulator's state (``sim/control`` read)."""
    return await node.query(keys.SIM_CONTROL, m.SimControl(action="read"), timeout=5.0)


async def still(node: Node) -> m.SimState:
    """The simulator's state once both wheels have stopped turning, and still do 0.2 s later
    (within 30 s)."""
    for _ in range(300):
        state = await sim_state(node)
        if abs(state.speed_left) + abs(state.speed_right) < 1e-4:
            await asyncio.sleep(0.2)
            again = await sim_state(node)
            if abs(again.speed_left) + abs(again.speed_right) < 1e-4:
                return again
        await asyncio.sleep(0.1)
    raise AssertionError(f"the wheels still turn: {state}")


@contextlib.asynccontextmanager
async def board(robot: Robot) -> Any:
    """A running `Board` on ``robot``'s bus."""
    async with robot.node("board") as node:
        b = Board(node)
        task = asyncio.create_task(b.run())
        try:
            await asyncio.wait_for(b.ready.wait(), 10)
            yield b
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task


__all__ = ["TEXT", "Board", "Http", "board", "sse_events", "wait_for", "webapi", "webapi_robot"]
