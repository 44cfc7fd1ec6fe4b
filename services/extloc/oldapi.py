"""The old PenguinPi localiser's HTTP API, so the course's ``pibot_client`` works unchanged.

The old localiser (qcr/PenguinPi-robot, ``software/python/localiser/localiser.py``) served::

    GET /pose/get?group=N   ->  {"pose": {"x": m, "y": m, "theta": rad}}
    GET /camera/get         ->  the overhead picture

``pibot_client.PiBot(..., localiser_ip, localiser_port)`` calls them as ``getLocalizerPose(group)``
and ``getLocalizerImage()``. The old localiser tracked one robot and ignored ``group``; here group
N is a robot (`tracker.groups`: ``extloc.group`` in the robot's config,
else its place in ``overhead.robots``). Its pose is the last one published, if the robot was seen
in the last `FRESH_S`; else 404 naming the robot (no stale pose). The picture is a JPEG of the
newest frame, encoded at most ``overhead.image_rate_hz`` times a second however often it is asked.
"""

from __future__ import annotations

import asyncio
import json
import time

import cv2
import numpy as np
from aiohttp import web

from icefloe.config import Overhead
from icefloe.errors import IcefloeError
from icefloe.schemas import messages as m

FRESH_S = 1.0
"""A robot's pose is served for this long after it was last seen, s."""


class Seen:
    """What the localizer has: the newest frame, and each robot's last pose with its time."""

    def __init__(self) -> None:
        self.frame: tuple[int, np.ndarray] | None = None
        self.poses: dict[str, tuple[float, m.ExternalPose]] = {}


def _json(status: int, body: dict) -> web.Response:
    return web.Response(status=status, text=json.dumps(body), content_type="application/json")


class OldApi:
    def __init__(self, overhead: Overhead, group_of: dict[int, str], seen: Seen) -> None:
        self.group_of, self.seen = group_of, seen
        self.image_period = 1.0 / overhead.image_rate_hz if overhead.image_rate_hz > 0 else 0.0
        self._jpeg: tuple[float, bytes] | None = None
        self._lock = asyncio.Lock()
        self.app = web.Application()
        self.app.router.add_get("/pose/get", self.pose)
        self.app.router.add_get("/camera/get", self.camera)
        self._runner: web.AppRunner | None = None

    async def start(self, host: str, port: int) -> None:
        self._runner = web.AppRunner(self.app, access_log=None)
        await self._runner.setup()
        try:
            await web.TCPSite(self._runner, host, port).start()
        except OSError as exc:
            await self._runner.cleanup()
            self._runner = None
            raise IcefloeError(f"overhead.http_port: cannot listen on {host}:{port}: {exc.strerror}") from None

    async def stop(self) -> None:
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

    async def pose(self, request: web.Request) -> web.Response:
        text = request.query.get("group", "")
        try:
            group = int(text)
        except ValueError:
            return _json(400, {"error": f"group: {text[:40]!r} is not a group number (GET /pose/get?group=N)"})
        robot = self.group_of.get(group)
        if robot is None:
            return _json(404, {"error": f"group {group}: no such group (groups: {sorted(self.group_of)})"})
        last = self.seen.poses.get(robot)
        if last is None or time.monotonic() - last[0] > FRESH_S:
            return _json(404, {"error": f"group {group}: robot {robot} is not in view of the overhead camera"})
        pose = last[1]
        return _json(200, {"pose": {"x": pose.x, "y": pose.y, "theta": pose.theta}})

    async def camera(self, _request: web.Request) -> web.Response:
        async with self._lock:  # one encoding at a time, however many ask
            now = time.monotonic()
            if self._jpeg is None or now - self._jpeg[0] >= self.image_period:
                frame = self.seen.frame
                if frame is None:
                    return _json(503, {"error": "the overhead camera has delivered no frame yet"})
                ok, data = await asyncio.to_thread(cv2.imencode, ".jpg", frame[1], [cv2.IMWRITE_JPEG_QUALITY, 80])
                if not ok:
                    return _json(500, {"error": "JPEG encoding failed"})
                self._jpeg = (now, data.tobytes())
            return web.Response(body=self._jpeg[1], content_type="image/jpeg")
