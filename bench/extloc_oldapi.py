"""The old localiser's API as the course's client reads it: how long each answer takes.

    .venv/bin/python bench/extloc_oldapi.py [--requests 300]

The lab localizer's old API (``services/extloc/oldapi.py``) served on loopback from a thread of
this process, with a robot seen and the simulated overhead camera's frame (1280x720, its pose
known), read by the course's own ``pibot_client`` (unchanged: tests/course_clients.py), one request at a
time: ``getLocalizerPose(1)`` (a robot seen), ``getLocalizerPose(7)`` (no robot: zeros and a log
line) and ``getLocalizerImage()`` with a new picture every request (``image_rate_hz = 0``: the
remap, arrow and PNG encoding each time; the service does it at most twice a second). Reference,
in the same run: the same client function against a bare aiohttp route that answers a constant
pose (the HTTP and JSON floor). Also the picture's maps (once per camera pose) and PNG size.
Figures are wall-clock milliseconds per call, p50 and p99.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

from aiohttp import web
from common import ROOT, free_port

from icefloe.config import Overhead
from icefloe.schemas import messages as m
from icefloe.services.extloc import oldapi, oldsquare
from icefloe.sim.overhead import OverheadRenderer, RobotView
from icefloe.vision.geometry import Intrinsics
from icefloe.vision.overhead import CameraPose
from icefloe.worldmap import load_world

sys.path.insert(0, str(ROOT / "tests"))
from course_clients import localiser_client  # the tests' folder, on the path just above


def serve(loop: asyncio.AbstractEventLoop, api: oldapi.OldApi, api_port: int, bare_port: int) -> None:
    """The old API and the bare reference route, on ``loop`` (its own thread)."""
    asyncio.set_event_loop(loop)

    async def constant(_request: web.Request) -> web.Response:
        return web.Response(text=json.dumps({"pose": {"x": 0.5, "y": 1.4, "theta": 114.6}}),
                            content_type="application/json")

    async def start() -> None:
        await api.start("127.0.0.1", api_port)
        bare = web.Application()
        bare.router.add_get("/pose/get", constant)
        runner = web.AppRunner(bare, access_log=None)
        await runner.setup()
        await web.TCPSite(runner, "127.0.0.1", bare_port).start()
        api.camera_known(*CAMERA)

    loop.run_until_complete(start())
    loop.run_forever()


INTRINSICS = Intrinsics.nominal(410.0, 1280, 720)
CAMERA = (INTRINSICS, CameraPose.looking_down(0.03, -0.02, 2.5, yaw=0.01, tilt=0.02))


def timed(call: Callable[[], object], n: int) -> tuple[float, float]:
    """p50, p99 of ``n`` calls, ms; each call must answer (pibot_client says None on its 1 s timeout)."""
    times = []
    for _ in range(n):
        start = time.perf_counter()
        assert call() is not None, "no answer within pibot_client's 1 s"
        times.append((time.perf_counter() - start) * 1000)
    cuts = statistics.quantiles(times, n=100)
    return cuts[49], cuts[98]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--requests", type=int, default=300, help="calls per figure")
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)

    start = time.perf_counter()
    maps = oldsquare.picture_maps(oldsquare.OldSquare(0.7, -1.0, 0.0), *CAMERA)
    maps_ms = (time.perf_counter() - start) * 1000
    start = time.perf_counter()
    oldsquare.picture_maps_exact(oldsquare.OldSquare(0.7, -1.0, 0.0), *CAMERA)
    exact_ms = (time.perf_counter() - start) * 1000
    del maps

    seen = oldapi.Seen()
    renderer = OverheadRenderer(load_world("lab"), CAMERA[0], CAMERA[1], "DICT_4X4_100")
    seen.frame = (time.time_ns(), renderer.render([RobotView(20, 0.16, 0.12, 1.2, 0.4, 2.0)]))
    seen.poses["a"] = (time.monotonic() + 1e6, m.ExternalPose(stamp=1, x=1.2, y=0.4, theta=2.0, covariance=[0.0] * 9))
    overhead = Overhead(old_square_x=0.7, old_square_y=-1.0, image_rate_hz=0.0)
    api = oldapi.OldApi(overhead, {1: "a"}, seen, logging.getLogger("bench"), {"a": 0.12})
    api_port, bare_port = free_port(), free_port()
    loop = asyncio.new_event_loop()
    threading.Thread(target=serve, args=(loop, api, api_port, bare_port), daemon=True).start()
    folder = Path(tempfile.mkdtemp(prefix="extloc-oldapi-"))
    bot, bare = localiser_client("127.0.0.1", api_port, folder), localiser_client("127.0.0.1", bare_port, folder)
    deadline = time.monotonic() + 10
    while bot.getLocalizerImage() is None:  # the maps made, the server up
        assert time.monotonic() < deadline, "the old API did not come up in 10 s"

    n = args.requests
    rows = [("getLocalizerPose, bare constant route (reference)", timed(lambda: bare.getLocalizerPose(1), n)),
            ("getLocalizerPose(1), a robot seen", timed(lambda: bot.getLocalizerPose(1), n)),
            ("getLocalizerPose(7), no robot (zeros)", timed(lambda: bot.getLocalizerPose(7), n)),
            ("getLocalizerImage(), a new picture each call", timed(bot.getLocalizerImage, max(n // 5, 20)))]
    png = len(api.old_picture._made[1]) if api.old_picture._made else 0
    print(f"old localiser API, {n} calls per figure, pibot_client unchanged, ms per call")
    for name, (p50, p99) in rows:
        print(f"  {name:<52} p50 {p50:6.2f}  p99 {p99:6.2f}")
    print(f"  picture maps, once per camera pose: {maps_ms:.0f} ms (every pixel projected: {exact_ms:.0f} ms)")
    print(f"  picture: 500x500 grey PNG, {png / 1000:.0f} kB")


if __name__ == "__main__":
    main()
