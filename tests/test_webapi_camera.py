"""``/camera/get``: the MJPEG stream, read as the old clients read it (OpenCV's VideoCapture).

The first two tests play the camera from this process (`camera`): ``camera/frames`` sent only
while something subscribes, as the camera service does, and the ``camera/frame`` query.
tests/test_camera_http.py reads the simulated camera with course-style clients."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import Robot
from webapi_helpers import jpeg, webapi, webapi_robot

from icefloe.schemas import keys
from icefloe.schemas import messages as m

HEAD = b"--frame\r\nContent-Type: image/jpeg\r\n\r\n"
"""Start of every part, as the old server wrote it (facts §5.2)."""


@pytest.fixture
def robot(make_robot):
    return webapi_robot(make_robot)


@dataclass
class Camera:
    image: bytes | None = None


@contextlib.asynccontextmanager
async def camera(robot: Robot) -> AsyncIterator[Camera]:
    """A stand-in camera: ``camera/frames`` at 20 Hz while matched, and ``camera/frame``."""
    cam = Camera()
    async with robot.node("camera") as node:
        frames = node.publisher(keys.FRAMES)

        async def latest(_request: m.Stop) -> m.Image:
            assert cam.image is not None
            return m.Image(stamp=time.time_ns(), width=320, height=240, data=cam.image)

        node.queryable(keys.FRAME, latest)

        async def publish() -> None:
            while True:
                if cam.image is not None and frames.matched:
                    frames.put(m.Image(stamp=time.time_ns(), width=320, height=240, data=cam.image))
                await asyncio.sleep(0.05)

        task = asyncio.create_task(publish())
        await asyncio.sleep(0.3)  # declarations reach the router
        try:
            yield cam
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task


def square_x(frame: np.ndarray) -> int:
    """Left edge of the white square our test frames carry, px."""
    return int(np.argmax(frame[60, :, 0] > 200))


async def test_stream_parts_are_the_old_servers(robot):
    async with webapi(robot) as http, camera(robot) as b:
        b.image = jpeg(shade=7)
        async with http.session.get(http.base + "/camera/get") as r:
            assert r.status == 200
            assert r.headers["Content-Type"] == "multipart/x-mixed-replace; boundary=frame"
            assert "Content-Length" not in r.headers and "Transfer-Encoding" not in r.headers
            part = await r.content.readexactly(len(HEAD) + len(b.image) + 2)
            assert part == HEAD + b.image + b"\r\n"
            assert await r.content.readexactly(len(HEAD)) == HEAD  # and the next part follows
            # A viewer still connected must not keep the service from stopping.
            assert http.proc.stop() == 0, http.proc.output


async def test_opencv_reads_the_stream_and_sees_new_frames(robot):
    async with webapi(robot) as http, camera(robot) as b:
        b.image = jpeg(shade=0)
        # As pibot_client opens it when given credentials in its ip (docs/webapi.md): the camera
        # is a read-only route, so the user and password in the URL must not get in the way.
        url = http.base.replace("http://", "http://penguin1:s3cret@") + "/camera/get"
        capture = await asyncio.to_thread(cv2.VideoCapture, url)
        try:
            assert capture.isOpened()
            ok, frame = await asyncio.to_thread(capture.read)
            assert ok and frame.shape == (240, 320, 3)
            assert abs(square_x(frame) - 20) <= 2
            b.image = jpeg(shade=100)  # a new picture must come through the same stream
            for _ in range(100):
                ok, frame = await asyncio.to_thread(capture.read)
                assert ok
                if abs(square_x(frame) - 120) <= 2:
                    break
            else:
                raise AssertionError("the stream never showed the new frame")
        finally:
            capture.release()


CAMERA_READY = (Path(__file__).resolve().parent.parent / "services" / "camera" / "__main__.py").exists()


@pytest.mark.skipif(not CAMERA_READY, reason="the camera service (services/camera) is not written yet")
async def test_opencv_reads_the_simulated_camera(make_robot):
    robot = webapi_robot(make_robot, "[camera]\nimage_rate_hz = 10.0\n")
    for service in ("sim", "camera"):
        robot.start(service)
    async with robot.node("tester") as node:
        images = node.subscribe(keys.IMAGE)
        # The simulated camera is up before the web API starts: three processes starting at once
        # on a busy machine may take webapi past its helper's 20 s.
        await asyncio.wait_for(anext(images), 60)
        async with webapi(robot) as http:
            capture = await asyncio.to_thread(cv2.VideoCapture, http.base + "/camera/get")
            try:
                assert capture.isOpened()
                ok, frame = await asyncio.to_thread(capture.read)
                assert ok
                cfg = robot.config.camera
                assert frame.shape == (cfg.image_height, cfg.image_width, 3)
                # The same picture as the camera's on the bus: the robot stands still, and only the
                # simulated sensor noise and lighting (a gain of up to +-15 %) differ from frame to
                # frame, so compare the pictures' structure (correlation), not their brightness.
                image = await asyncio.wait_for(anext(images), 10)
                bus = cv2.imdecode(np.frombuffer(image.data, np.uint8), cv2.IMREAD_COLOR)
                assert np.corrcoef(frame.astype(float).ravel(), bus.astype(float).ravel())[0, 1] > 0.9
                assert frame.std() > 10  # a real picture (walls, floor, markers), not a blank frame
            finally:
                capture.release()
