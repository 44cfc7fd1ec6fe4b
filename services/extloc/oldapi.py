"""The old PenguinPi localiser's HTTP API, answered as its clients read it.

The old localiser (qcr/PenguinPi-robot, ``software/python/localiser/localiser.py``) served::

    GET /pose/get?group=N   ->  200 {"pose": {"x": m, "y": m, "theta": degrees}}, in its square's frame
    GET /camera/get         ->  its square seen from above: 500 x 500, grey, PNG

and the course's ``pibot_client`` reads them as ``getLocalizerPose(group)`` (``json.loads(resp.text)
["pose"]``: it catches only a timeout, so any other answer kills the student's program) and
``getLocalizerImage()``; MATLAB's ``PiBot.m`` as ``jsondecode(webread(...))`` (so the JSON goes
out as Flask sent it, ``text/html``) and ``webread`` of the PNG, always on port 8080. The old
localiser tracked one robot and ignored ``group``; it answered ``0, 0, 0`` when it saw no robot.
Here group N is a robot (`tracker.groups`: ``extloc.group`` in the robot's config, else its place
in ``overhead.robots``), its pose the last one published if the robot was seen in the last
`FRESH_S` (no stale pose), turned into the old square's frame and units (`oldsquare.py`). Every
other case, a robot not seen, a group that is no robot, a query that is no group at all, is
answered as the old one did, 200 and ``0, 0, 0``, with an ``"error"`` beside the pose that says
which case it was (the client ignores it) and one rate-limited log line naming the group.

Beyond the old API, ``GET /camera/frame`` is the newest whole overhead frame as a JPEG. Each
picture is encoded at most ``overhead.image_rate_hz`` times a second, however often it is asked.
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
import time
from collections.abc import Callable, Mapping

import cv2
import numpy as np
from aiohttp import web

from icefloe.config import Overhead
from icefloe.errors import IcefloeError
from icefloe.logs import LimitedLog
from icefloe.schemas import messages as m
from icefloe.vision.geometry import Intrinsics
from icefloe.vision.overhead import CameraPose

from . import oldsquare
from .oldsquare import OldSquare

FRESH_S = 1.0
"""A robot's pose is served for this long after it was last seen, s."""
MAX_GROUP = 9999
"""The largest group number (``extloc.group``'s range)."""
LOG_PERIOD_S = 10.0
"""The log names each group answered with zeros once per this period, s."""


class Seen:
    """What the localizer has: the newest frame, each robot's last pose with its time, and the
    overhead camera (its lens and pose) once it is known."""

    def __init__(self) -> None:
        self.frame: tuple[int, np.ndarray] | None = None
        self.poses: dict[str, tuple[float, m.ExternalPose]] = {}
        self.camera: tuple[Intrinsics, CameraPose] | None = None


def _json(status: int, body: dict) -> web.Response:
    return web.Response(status=status, text=json.dumps(body), content_type="application/json")


def _as_flask(body: dict) -> web.Response:
    """JSON text as the old localiser's Flask sent a ``str``: 200, text/html; charset=utf-8. MATLAB's
    PiBot.m decodes it itself (``jsondecode(webread(...))``); ``webread`` would decode an
    ``application/json`` body first, and PiBot's ``jsondecode`` of the result would fail."""
    return web.Response(text=json.dumps(body), content_type="text/html", charset="utf-8")


NOT_SEEN = {"x": 0, "y": 0, "theta": 0}
"""The old localiser's answer when it saw no robot (Python ints, as it sent them)."""


def group_number(text: str | None) -> int | None:
    """A group number of a query (decimal digits, 1 to `MAX_GROUP`), else None. Never `int()` of a
    long string: Python refuses more than 4300 digits with an error of its own."""
    if text is None or not (text.isascii() and text.isdigit()):
        return None
    digits = text.lstrip("0")
    if len(digits) > len(str(MAX_GROUP)):
        return None
    group = int(digits or "0")
    return group if group >= 1 else None


class Picture:
    """One encoded picture, made again at most once per ``period`` s, one encoding at a time."""

    def __init__(self, period: float, content_type: str, make: Callable[[], bytes | str]) -> None:
        self.period, self.content_type, self.make = period, content_type, make
        self._made: tuple[float, bytes] | None = None
        self._lock = asyncio.Lock()

    async def response(self) -> web.Response:
        async with self._lock:
            now = time.monotonic()
            if self._made is None or now - self._made[0] >= self.period:
                data = await asyncio.to_thread(self.make)
                if isinstance(data, str):  # why there is no picture
                    return _json(503, {"error": data})
                self._made = (now, data)
            return web.Response(body=self._made[1], content_type=self.content_type)


class OldApi:
    def __init__(self, overhead: Overhead, group_of: dict[int, str], seen: Seen, log: logging.Logger,
                 heights: Mapping[str, float] | None = None) -> None:
        """``heights``: each robot's top marker above the floor, m (where its arrow goes in the picture)."""
        self.group_of, self.seen = group_of, seen
        self.heights = dict(heights or {})
        self.group_by_robot = {robot: group for group, robot in group_of.items()}
        self.square = OldSquare.from_config(overhead)
        self.limited = LimitedLog(log, burst=1, limit=10, period=LOG_PERIOD_S)
        period = 1.0 / overhead.image_rate_hz if overhead.image_rate_hz > 0 else 0.0
        self.old_picture = Picture(period, "image/png", self._old_png)
        self.frame_picture = Picture(period, "image/jpeg", self._frame_jpeg)
        self._maps: tuple[tuple[Intrinsics, CameraPose], tuple[np.ndarray, np.ndarray]] | None = None
        self._maps_lock = threading.Lock()
        self._background: set[asyncio.Task] = set()
        self.app = web.Application()
        self.app.router.add_get("/pose/get", self.pose)
        self.app.router.add_get("/camera/get", self.camera)
        self.app.router.add_get("/camera/frame", self.frame)
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

    def fresh(self, robot: str) -> m.ExternalPose | None:
        """The robot's last pose if it was seen in the last `FRESH_S`, else None."""
        last = self.seen.poses.get(robot)
        if last is None or time.monotonic() - last[0] > FRESH_S:
            return None
        return last[1]

    def answer(self, text: str | None) -> tuple[dict, str | None, str]:
        """The answer to ``/pose/get?group=<text>`` (None: no ``group``); what was wrong, if anything;
        and the kind of log line that says so (one per group number, one for every bad query)."""
        group = group_number(text)
        if group is None:
            if text is None:
                return {"pose": NOT_SEEN}, "/pose/get without ?group=N", "bad group"
            return {"pose": NOT_SEEN}, f"/pose/get?group={text[:40]!r}: not a group number (1 to {MAX_GROUP})", \
                "bad group"
        robot = self.group_of.get(group)
        if robot is None:
            return ({"pose": NOT_SEEN}, f"/pose/get?group={group}: no robot has group {group} "
                    f"(groups: {', '.join(map(str, sorted(self.group_of)))})", f"group {group}")
        pose = self.fresh(robot)
        if pose is None:
            return ({"pose": NOT_SEEN}, f"/pose/get?group={group}: robot {robot} not seen by the overhead camera "
                    f"in the last {FRESH_S:g} s", f"group {group}")
        x, y, theta = self.square.pose(pose.x, pose.y, pose.theta)
        return {"pose": {"x": x, "y": y, "theta": theta}}, None, f"group {group}"

    async def pose(self, request: web.Request) -> web.Response:
        body, problem, kind = self.answer(request.query.get("group"))
        if problem is not None:
            self.limited.warning(kind, "%s: answered 0, 0, 0, as the old localiser did", problem)
            body = {**body, "error": problem}
        return _as_flask(body)

    async def camera(self, _request: web.Request) -> web.Response:
        return await self.old_picture.response()

    async def frame(self, _request: web.Request) -> web.Response:
        return await self.frame_picture.response()

    def camera_known(self, intrinsics: Intrinsics, pose: CameraPose) -> None:
        """The overhead camera's lens and pose, once known (on the loop). The picture's maps are made
        now, on a worker thread (0.6 s), not by the first ``/camera/get``, which pibot_client gives 1 s."""
        self.seen.camera = (intrinsics, pose)
        task = asyncio.get_running_loop().create_task(asyncio.to_thread(self._picture_maps, self.seen.camera))
        self._background.add(task)
        task.add_done_callback(self._background.discard)

    def _picture_maps(self, camera: tuple[Intrinsics, CameraPose]) -> tuple[np.ndarray, np.ndarray]:
        """The old picture's maps for this camera, made once (worker threads)."""
        with self._maps_lock:
            if self._maps is None or self._maps[0] is not camera:
                self._maps = (camera, oldsquare.picture_maps(self.square, *camera))
            return self._maps[1]

    def _old_png(self) -> bytes | str:
        """The old localiser's picture of its square (worker thread)."""
        frame, camera = self.seen.frame, self.seen.camera
        if frame is None:
            return "the overhead camera has delivered no frame yet"
        if camera is None:
            return "the overhead camera's pose is not known yet (no floor markers in view, no overhead.pose)"
        maps = self._picture_maps(camera)
        robots = []
        for robot, group in sorted(self.group_by_robot.items(), key=lambda item: item[1]):
            pose = self.fresh(robot)
            if pose is not None:
                x, y = oldsquare.seen_on_floor(camera[1], pose.x, pose.y, self.heights.get(robot, 0.0))
                robots.append((str(group), self.square.pose(x, y, pose.theta)))
        ok, data = cv2.imencode(".png", oldsquare.picture(frame[1], maps, robots))
        return data.tobytes() if ok else "PNG encoding failed"

    def _frame_jpeg(self) -> bytes | str:
        """The newest whole overhead frame (worker thread)."""
        frame = self.seen.frame
        if frame is None:
            return "the overhead camera has delivered no frame yet"
        ok, data = cv2.imencode(".jpg", frame[1], [cv2.IMWRITE_JPEG_QUALITY, 80])
        return data.tobytes() if ok else "JPEG encoding failed"
