"""The old PenguinPi localiser's API as its clients read it (services/extloc/oldapi.py, oldsquare.py).

The course's own client, unchanged (loaded by its commit and hash: tests/course_clients.py), reads the
lab localizer's HTTP API served in this process: a robot's pose in the old square's frame and in
degrees, ``0, 0, 0`` for a robot not seen lately and for a group that is no robot (the client must
not raise), the old square's picture; hostile query strings get a 200 with zeros and a reason, one
log line per group, and the service keeps serving through floods and stalled connections. The
pictures come from the simulated overhead camera. No processes; 3-6 s
(tests/test_extloc_overhead_lab.py runs the same client against the real service in a simulated lab).
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from pathlib import Path

import aiohttp
import cv2
import numpy as np
import pytest
from conftest import free_port
from course_clients import localiser_client

from icefloe.config import Overhead
from icefloe.schemas import messages as m
from icefloe.services.extloc import locate, oldapi, oldsquare
from icefloe.services.extloc.oldsquare import OldSquare
from icefloe.sim.overhead import OverheadRenderer, RobotView
from icefloe.vision.geometry import Intrinsics
from icefloe.vision.overhead import CameraPose, flat_square_corners
from icefloe.worldmap import load_world

DICTIONARY = "DICT_4X4_100"


def test_old_square_frame_and_units() -> None:
    """World poses → metres from the square's corner along its sides, and degrees CCW from its +x,
    in (-180, 180]; the default square is the lab world's clear one, x and y in [-0.5, 1.5] m."""
    square = OldSquare.from_config(Overhead())
    assert square == OldSquare(-0.5, -0.5, 0.0)
    assert square.pose(-0.5, -0.5, 0.0) == (0.0, 0.0, 0.0)
    x, y, theta = square.pose(0.0, 0.0, math.pi / 2)  # the lab's start pose, turned left
    assert (x, y) == (0.5, 0.5) and theta == pytest.approx(90.0)
    assert square.pose(1.5, 1.5, math.pi)[2] == pytest.approx(180.0)
    assert square.pose(1.5, 1.5, -math.pi)[2] == pytest.approx(180.0)  # never -180
    assert square.pose(1.0, 0.0, -0.25)[2] == pytest.approx(math.degrees(-0.25))
    turned = OldSquare(2.7, -1.0, math.pi / 2)  # corner at the world's (2.7, -1), its +x along the world's +y
    x, y, theta = turned.pose(2.7, 0.0, 0.0)
    assert (x, y, theta) == pytest.approx((1.0, 0.0, -90.0))
    x, y, _ = turned.pose(1.7, 0.0, 0.0)
    assert (x, y) == pytest.approx((1.0, 1.0))
    assert turned.world(np.array([[1.0, 1.0]])) == pytest.approx(np.array([[1.7, 0.0, 0.0]]))


def test_old_square_config_is_checked_and_named() -> None:
    """A square placed nowhere (NaN, infinite, far away) or turned by a number that is no angle in
    radians (degrees by mistake) is refused, naming the key, before anything starts."""
    from icefloe import config as config_mod
    from icefloe.errors import ConfigError

    for key, value, message in [("old_square_x", float("nan"), ">= -1000"), ("old_square_y", float("inf"), "<= 1000"),
                                ("old_square_x", 5000.0, "<= 1000"), ("old_square_yaw", 90.0, "<= 6.28"),
                                ("old_square_yaw", "east", "Expected `float`")]:
        with pytest.raises(ConfigError, match=rf"^lab\.toml: overhead\.{key}: .*{message}"):
            config_mod.parse({"overhead": {key: value}}, "lab.toml")
    assert config_mod.parse({"overhead": {"old_square_yaw": -1.5}}, "lab.toml").overhead.old_square_yaw == -1.5


def test_default_old_square_is_the_lab_worlds_clear_square() -> None:
    """The default square (x, y in [-0.5, 1.5] m) holds no obstacle and no floor marker of the lab world,
    and the robots' start pose (the origin) is inside it: course code that drives to a point of the
    old square drives on clear floor."""
    world = load_world("lab")
    square = OldSquare.from_config(Overhead())
    grid = np.linspace(0.0, oldsquare.SIDE_M, 41)  # every 5 cm
    points = square.world(np.array([[x, y] for x in grid for y in grid]))
    assert min(world.clearance(x, y) for x, y, _ in points) > 0.05
    for marker in world.floor_markers:  # a marker's whole square, its corners 0.71 of its side from its centre
        x, y, _ = square.pose(marker.x, marker.y, 0.0)
        reach = marker.size * 0.71
        assert not (-reach < x < oldsquare.SIDE_M + reach and -reach < y < oldsquare.SIDE_M + reach), marker
    x, y, _ = square.pose(0.0, 0.0, 0.0)
    assert 0 < x < oldsquare.SIDE_M and 0 < y < oldsquare.SIDE_M


@pytest.fixture(scope="module")
def overhead() -> tuple[Intrinsics, CameraPose, OverheadRenderer]:
    intrinsics = Intrinsics.nominal(410.0, 1280, 720)
    camera = CameraPose.looking_down(0.03, -0.02, 2.5, yaw=0.01, tilt=0.02)  # hung a little off
    return intrinsics, camera, OverheadRenderer(load_world("lab"), intrinsics, camera, DICTIONARY, noise=0.0)


@pytest.mark.parametrize("square", [OldSquare(0.7, -1.0, 0.0), OldSquare(2.7, -1.0, math.pi / 2)])
def test_old_picture_shows_the_square_from_above_with_its_y_up(overhead, square: OldSquare) -> None:
    """The floor marker 81 (world (1.7, 0), 20 cm, its top edge towards the world's +x) lies at the
    middle of both squares: in their pictures, its corners are where the old frame puts them, within
    a pixel (4 mm); in the square turned by 90 degrees, turned by 90 degrees too (not mirrored)."""
    intrinsics, camera, renderer = overhead
    image = oldsquare.picture(renderer.render([]), oldsquare.picture_maps(square, intrinsics, camera), [])
    assert image.shape == (500, 500) and image.dtype == np.uint8
    seen = locate.find_markers(locate.make_detector(DICTIONARY), cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    assert set(seen) == {81}
    expected = []
    for wx, wy, _ in flat_square_corners(1.7, 0.0, 0.0, 0.0, 0.1):
        x, y, _ = square.pose(wx, wy, 0.0)
        expected.append(oldsquare.to_picture(x, y))
    assert np.abs(seen[81] - np.array(expected)).max() < 1.0, (seen[81], expected)


def test_old_picture_maps_interpolated_are_the_projected_ones() -> None:
    """The maps projected every 4 pixels and interpolated between are within 0.01 px of projecting
    every pixel, under a wide lens's distortion and a tilted, turned camera (measured: 0.002 px)."""
    k = np.array([[420.0, 0.0, 645.0], [0.0, 418.0, 355.0], [0.0, 0.0, 1.0]])
    lens = Intrinsics(k, np.array([-0.28, 0.09, 0.001, -0.0005, -0.01]), 1280, 720)
    camera = CameraPose.looking_down(0.1, -0.05, 2.5, yaw=0.2, tilt=0.03)
    square = OldSquare(-0.7, -0.2, 0.4)
    fast, exact = oldsquare.picture_maps(square, lens, camera), oldsquare.picture_maps_exact(square, lens, camera)
    assert max(np.abs(fast[0] - exact[0]).max(), np.abs(fast[1] - exact[1]).max()) < 0.01


class Lines(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


def pose(x: float, y: float, theta: float) -> m.ExternalPose:
    return m.ExternalPose(stamp=1, x=x, y=y, theta=theta, covariance=[0.0] * 9)


async def test_upstream_client_reads_old_units_and_zeros_and_survives_hostile_queries(overhead, tmp_path: Path) -> None:
    """Group 1 seen (its pose in the old square's frame, degrees), group 2 seen 5 s ago (no stale
    pose), group 5 never seen, group 7 no robot, and the client's own default group (None): the
    client returns numbers for each and never raises; then query strings a student might send."""
    intrinsics, camera, renderer = overhead
    lines = Lines()
    log = logging.getLogger("test-extloc-oldapi")
    log.addHandler(lines)
    square = OldSquare(0.7, -1.0, 0.0)  # holds the floor marker 81 and robot a
    ov = Overhead(old_square_x=square.x, old_square_y=square.y, old_square_yaw=square.yaw, image_rate_hz=2.0)
    seen = oldapi.Seen()
    seen.poses["a"] = (time.monotonic() + 3600, pose(1.2, 0.4, 2.0))  # fresh for the whole test
    seen.poses["b"] = (time.monotonic() - 5.0, pose(3.0, 0.0, 0.0))
    api = oldapi.OldApi(ov, {1: "a", 2: "b", 5: "c"}, seen, log, {"a": 0.12})
    port = free_port()
    await api.start("127.0.0.1", port)
    try:
        bot = localiser_client("127.0.0.1", port, tmp_path)
        x, y, theta = await asyncio.to_thread(bot.getLocalizerPose, 1)
        assert (x, y) == pytest.approx((0.5, 1.4)) and theta == pytest.approx(math.degrees(2.0))
        for group in (2, 5, 7, None):
            assert await asyncio.to_thread(bot.getLocalizerPose, group) == (0.0, 0.0, 0.0), group
        assert any("group=2: robot b not seen" in line for line in lines.lines), lines.lines
        assert any("group=5: robot c not seen" in line for line in lines.lines), lines.lines
        assert any("group=7: no robot has group 7 (groups: 1, 2, 5)" in line for line in lines.lines), lines.lines

        async with aiohttp.ClientSession(f"http://127.0.0.1:{port}") as http:
            async def get(path: str) -> tuple[int, dict]:
                async with http.get(path) as r:
                    return r.status, await r.json(content_type=None)

            # As the old Flask sent it: MATLAB's PiBot.m jsondecodes the text itself.
            async with http.get("/pose/get?group=1") as r:
                assert r.headers["Content-Type"] == "text/html; charset=utf-8"

            hostile = {"group=abc": "'abc'", "group=-1": "'-1'", "group=0": "'0'", "group=1.5": "'1.5'",
                       "group=%00": "'\\x00'", "group=" + "9" * 5000: "'9999", "group=99999999999999999999": "'9999",
                       "group=%D9%A1": "'\u0661'", "group=": "''", "": "without ?group=N", "grp=1": "without ?group=N"}
            for query, named in hostile.items():
                status, answer = await get(f"/pose/get?{query}")
                assert status == 200 and answer["pose"] == {"x": 0, "y": 0, "theta": 0}, (query, answer)
                assert named in answer["error"] and len(answer["error"]) < 120, (query, answer)
            # Leading zeros are still group 1; a second group= is not read.
            assert (await get("/pose/get?group=" + "0" * 5000 + "1"))[1]["pose"]["x"] == pytest.approx(0.5)
            assert (await get("/pose/get?group=1&group=7"))[1]["pose"]["x"] == pytest.approx(0.5)
            # A flood of unknown groups and bad queries: answered, and a few log lines, not a thousand.
            before = len(lines.lines)
            answers = await asyncio.gather(*(get(f"/pose/get?group={q}") for q in [7, "x", 8, 9] * 250))
            assert all(status == 200 for status, _ in answers)
            said = [line for line in lines.lines[before:] if "answered 0, 0, 0" in line]
            assert len(said) <= 2, said  # groups 8 and 9; 7 and the bad query were named already
            # Ten connections that stall halfway through their request line hold up nobody.
            stalled = [await asyncio.open_connection("127.0.0.1", port) for _ in range(10)]
            for _, writer in stalled:
                writer.write(b"GET /pose/get?gro")
                await writer.drain()
            x, _, _ = await asyncio.to_thread(bot.getLocalizerPose, 1)  # still serving, within its 1 s timeout
            assert x == pytest.approx(0.5)
            for _, writer in stalled:
                writer.close()

            # The picture: none before the first frame (the client gets None, no exception), then
            # the old square's, grey, 500 x 500, as a PNG, however many ask (bounded work).
            assert await asyncio.to_thread(bot.getLocalizerImage) is None
            status, answer = await get("/camera/get")
            assert status == 503 and "no frame yet" in answer["error"]
            seen.frame = (time.time_ns(), renderer.render([RobotView(20, 0.16, 0.12, 1.2, 0.4, 2.0)]))
            status, answer = await get("/camera/get")
            assert status == 503 and "pose is not known yet" in answer["error"]
            api.camera_known(intrinsics, camera)
            encoded = 0
            real_imencode = oldapi.cv2.imencode

            def counting(*args: object) -> object:
                nonlocal encoded
                encoded += 1
                return real_imencode(*args)

            oldapi.cv2.imencode = counting
            try:
                async def picture(path: str) -> tuple[str, bytes]:
                    async with http.get(path) as r:
                        assert r.status == 200, (path, await r.text())
                        return r.content_type, await r.read()

                start = time.monotonic()
                bodies = await asyncio.gather(*(picture(p) for p in ["/camera/get"] * 40 + ["/camera/frame"] * 10))
                elapsed = time.monotonic() - start
            finally:
                oldapi.cv2.imencode = real_imencode
            assert all(kind == "image/png" and body[:8] == b"\x89PNG\r\n\x1a\n" for kind, body in bodies[:40])
            assert all(kind == "image/jpeg" and body[:2] == b"\xff\xd8" for kind, body in bodies[40:])
            assert encoded <= 2 * (1 + math.ceil(elapsed * 2.0)), (encoded, elapsed)  # not 50
            png = cv2.imdecode(np.frombuffer(bodies[0][1], np.uint8), cv2.IMREAD_UNCHANGED)
            assert png.shape == (500, 500)  # grey, as the old localiser's
        picture = await asyncio.to_thread(bot.getLocalizerImage)
        assert picture.shape == (500, 500, 3)
        # Robot a's arrow: white along its heading (up the picture for +y), from where its top marker
        # (12 cm up, 1.24 m from below the lens) shows in the picture: 6.3 cm (16 px) outward of its pose.
        x, y = oldsquare.seen_on_floor(camera, 1.2, 0.4, 0.12)
        assert math.hypot(x - 1.2, y - 0.4) == pytest.approx(0.063, abs=0.002)
        top = locate.find_markers(locate.make_detector(DICTIONARY), cv2.cvtColor(oldsquare.picture(
            seen.frame[1], oldsquare.picture_maps(square, intrinsics, camera), []), cv2.COLOR_GRAY2BGR))[20]
        col, row = oldsquare.to_picture(*square.pose(x, y, 0.0)[:2])
        assert np.hypot(*(top.mean(axis=0) - (col, row))) < 1.0, (top, col, row)
        for along in (10, 20, 30):
            tip = (round(row - along * math.sin(2.0)), round(col + along * math.cos(2.0)))
            assert picture[tip].min() > 200, (along, picture[tip])
    finally:
        log.removeHandler(lines)
        await api.stop()
