"""camera: frames in, ArUco landmarks and JPEG images out.

* A capture thread reads frames from the source of ``camera.source`` (see
  sources.py) into a one-frame slot: the **latest frame wins**. When detection
  falls behind, the frames it never saw are dropped and counted, never queued.
* Detection runs on every frame it takes, whatever the image rate, and publishes
  ``camera/landmarks`` stamped with the frame's capture time.
* ``camera/image``: a smaller JPEG at ``camera.image_rate_hz`` (the Wi-Fi is shared
  by a class); ``camera/snapshot``: one full-resolution JPEG of the latest frame.
* ``camera/frames``: every captured frame as the smaller JPEG, sent by the capture thread
  itself (no detection in the way), but only while something subscribes (the web API while
  an HTTP client watches ``/camera/get``); ``camera/frame``: the latest as one smaller JPEG;
  ``camera/info``: the intrinsics of the smaller JPEGs (see frames.py).
* A missing or failing camera, or a bad frame, is logged and retried: the service
  never dies for it. Only when the camera's software is not installed at all (picamera2,
  an apt package of Raspberry Pi OS) does it exit at once with one line naming the package,
  with `CANNOT_START` (2): neither `icefloe up` nor the robot's unit restarts it, and the
  rest of the robot runs.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time

import numpy as np

from icefloe.config import RobotConfig
from icefloe.errors import ConfigError
from icefloe.runtime import Node, Publisher, run
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.worldmap import load_world

from .detection import BadFrame, Detector, check_frame
from .frames import Frames, camera_info
from .geometry import Intrinsics, Mount
from .sources import SimSource, Source, SourceError, open_source, picamera2_class

RETRY_S = 2.0
SNAPSHOT_QUALITY = 90
"""JPEG quality of ``camera/snapshot`` (calibration images: sharper than the stream's)."""
REPORT_S = 10.0


class LatestFrame:
    """A one-frame slot between the capture thread and detection; counts what was overwritten."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._frame: tuple[int, np.ndarray] | None = None
        self.latest: tuple[int, np.ndarray] | None = None
        """The newest frame, kept for snapshots."""
        self.captured = 0
        self.dropped = 0

    def put(self, frame: tuple[int, np.ndarray]) -> None:
        with self._cond:
            if self._frame is not None:
                self.dropped += 1
            self._frame = self.latest = frame
            self.captured += 1
            self._cond.notify()

    def take(self, timeout: float) -> tuple[int, np.ndarray] | None:
        with self._cond:
            if self._frame is None:
                self._cond.wait(timeout)
            frame, self._frame = self._frame, None
            return frame


def capture(config: RobotConfig, node: Node, slot: LatestFrame, stop: threading.Event,
            sources: list[Source], stream: Publisher[m.Image], small: Frames) -> None:
    """The capture thread: open the source, read frames into ``slot``, reopen after failures;
    while something subscribes to ``stream`` (``camera/frames``), send it each frame at once."""
    cam = config.camera
    source: Source | None = None
    while not stop.is_set():
        try:
            if source is None:
                source = open_source(config)
                sources[:] = [source]
                node.log.info("camera %r open", cam.source)
            stamp, image = source.read()
            frame = (stamp, check_frame(image, cam.width, cam.height))
            slot.put(frame)
            if stream.matched:  # someone watches: ~2 ms at 320x240, no cost otherwise
                stream.put(small.of(frame))
        except BadFrame as exc:
            node.limited.warning("bad frame", "camera %r: bad frame skipped (%s)", cam.source, exc)
        except Exception as exc:  # a camera that fails must not take the service with it
            node.log.warning("camera %r failed: %s; retrying in %.0f s", cam.source, exc, RETRY_S)
            if source is not None:
                with contextlib.suppress(Exception):
                    source.close()
            source = None
            sources.clear()
            stop.wait(RETRY_S)
    if source is not None:
        source.close()


def make_detector(config: RobotConfig) -> Detector:
    cam = config.camera
    try:
        world = load_world(config.localizer.world)
        sizes = world.sizes()  # markers, and the faces of marker blocks
    except ConfigError:
        sizes = {}  # no map: every marker is taken to have camera.marker_size
    return Detector(cam.dictionary, Intrinsics.from_config(cam), Mount.from_config(cam), sizes, cam.marker_size)


async def main(config: RobotConfig) -> None:
    cam = config.camera
    if cam.source == "picamera2":
        picamera2_class()  # CameraMissing: one line, exit 2 (run() says it), no restart
    detector = make_detector(config)  # ConfigError for a bad calibration file: run() says so, exits
    info = camera_info(cam, Intrinsics.from_config(cam))
    async with Node("camera", config) as node:
        slot, stop, sources = LatestFrame(), threading.Event(), []
        small = Frames(cam)
        full = Frames(cam, full=True, quality=SNAPSHOT_QUALITY)
        landmarks = node.publisher(keys.LANDMARKS)
        images = node.publisher(keys.IMAGE)
        stream = node.publisher(keys.FRAMES)

        async def snapshot(_request: m.Stop) -> m.Image:
            frame = slot.latest
            if frame is None:
                raise SourceError(f"camera {cam.source!r} has delivered no frame yet")
            return await asyncio.to_thread(full.of, frame)

        node.queryable(keys.SNAPSHOT, snapshot)

        async def latest_small(_request: m.Stop) -> m.Image:
            frame = slot.latest
            if frame is None:
                raise SourceError(f"camera {cam.source!r} has delivered no frame yet")
            return await asyncio.to_thread(small.of, frame)

        async def intrinsics(_request: m.Stop) -> m.CameraInfo:
            return info

        node.queryable(keys.FRAME, latest_small)
        node.queryable(keys.CAMERA_INFO, intrinsics)

        async def feed_truth() -> None:  # only for the simulated camera
            async for truth in node.subscribe(keys.TRUTH):
                for source in sources:
                    if isinstance(source, SimSource):
                        source.set_truth(truth)

        thread = threading.Thread(target=capture, args=(config, node, slot, stop, sources, stream, small),
                                  name="camera-capture", daemon=True)
        thread.start()
        truth_task = asyncio.create_task(feed_truth()) if cam.source == "sim" else None
        image_period = 1.0 / cam.image_rate_hz if cam.image_rate_hz > 0 else float("inf")
        next_image = next_report = time.monotonic()
        detected = 0
        try:
            while True:
                frame = await asyncio.to_thread(slot.take, 0.5)
                now = time.monotonic()
                if now >= next_report:
                    if slot.dropped:
                        node.log.info("camera: %d frames captured, %d detected, %d dropped (detection behind)",
                                      slot.captured, detected, slot.dropped)
                    next_report = now + REPORT_S
                if frame is None:
                    continue
                stamp, image = frame
                found = await asyncio.to_thread(detector.detect, image)
                detected += 1
                landmarks.put(m.Landmarks(stamp=stamp, landmarks=found))
                if now >= next_image:
                    next_image = now + image_period
                    images.put(await asyncio.to_thread(small.of, frame))
        finally:
            stop.set()
            if truth_task is not None:
                truth_task.cancel()
            await asyncio.to_thread(thread.join, RETRY_S + 1.0)


if __name__ == "__main__":
    run(main)
