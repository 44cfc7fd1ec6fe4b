"""camera: frames in, ArUco landmarks and JPEG images out.

* A capture thread (`icefloe.vision.capture`) reads frames from the source of ``camera.source``
  (sources.py) into a one-frame slot: the **latest frame wins**. When detection
  falls behind, the frames it never saw are dropped and counted, never queued.
* Detection runs ``camera.detection_rate_hz`` times a second (0: on every frame it takes),
  whatever the image rate, and publishes ``camera/landmarks`` stamped with the frame's capture
  time (its arrival less the capture latency the calibration measured, if it did). It is the
  camera's main cost, about proportional to the frame's pixels times that rate: a robot's config
  chooses it (docs/camera.md, "What the camera costs").
* **At rest** it searches fewer: while its picture does not change (a small grey thumbnail of
  each frame due, compared with the still spell's first: rest.py) for ``camera.rest_after_s``,
  only ``camera.rest_detection_rate_hz`` frames a second; the first frame that differs is
  searched at once and ends the rest (docs/camera.md, "The camera at rest").
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
import time

from icefloe.config import RobotConfig
from icefloe.runtime import Node, run
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.vision.capture import Capture
from icefloe.vision.geometry import Intrinsics, calibration_extras
from icefloe.vision.sources import Frame, SourceError, picamera2_class
from icefloe.worldmap import load_world

from .detection import make_detector
from .frames import Frames, camera_info
from .rest import DetectionRest, thumbnail
from .sources import open_camera

SNAPSHOT_QUALITY = 90
"""JPEG quality of ``camera/snapshot`` (calibration images: sharper than the stream's)."""


async def main(config: RobotConfig) -> None:
    cam = config.camera
    if cam.source == "picamera2":
        picamera2_class()  # CameraMissing: one line, exit 2 (run() says it), no restart
    detector = make_detector(config)  # ConfigError for a bad calibration file: run() says so, exits
    if cam.source == "sim":
        load_world(config.sim.world)  # a bad world or track layout: ConfigError, one line, no retrying
    latency_s = calibration_extras(cam).latency_s
    info = camera_info(cam, Intrinsics.from_config(cam), latency_s)
    async with Node("camera", config) as node:
        small = Frames(cam)
        full = Frames(cam, full=True, quality=SNAPSHOT_QUALITY)
        landmarks = node.publisher(keys.LANDMARKS)
        images = node.publisher(keys.IMAGE)
        stream = node.publisher(keys.FRAMES)

        def send_while_watched(frame: Frame) -> None:  # the capture thread
            if stream.matched:  # someone watches: ~2 ms at 320x240, no cost otherwise
                stream.put(small.of(frame))

        # the simulated camera reads the newest sim/truth at each frame it renders (one decoded a frame)
        truth = node.latest(keys.TRUTH) if cam.source == "sim" else None
        capture = Capture("camera", cam.source, lambda: open_camera(config, latency_s, truth.get if truth else None),
                          cam.width, cam.height,
                          log=node.log,
                          limited=node.limited, thread_name="camera-capture", on_frame=send_while_watched)

        def newest() -> Frame:
            if capture.slot.latest is None:
                raise SourceError(f"camera {cam.source!r} has delivered no frame yet")
            return capture.slot.latest

        async def snapshot(_request: m.Stop) -> m.Image:
            return await asyncio.to_thread(full.of, newest())

        async def latest_small(_request: m.Stop) -> m.Image:
            return await asyncio.to_thread(small.of, newest())

        async def intrinsics(_request: m.Stop) -> m.CameraInfo:
            return info

        node.queryable(keys.SNAPSHOT, snapshot)
        node.queryable(keys.FRAME, latest_small)
        node.queryable(keys.CAMERA_INFO, intrinsics)

        capture.start()
        image_period = 1.0 / cam.image_rate_hz if cam.image_rate_hz > 0 else float("inf")
        next_image = next_detection = time.monotonic()
        detection_period = 1.0 / cam.detection_hz
        early = 0.5 / cam.fps  # a frame this early is the one due: frames come at fps, with jitter
        every_frame = cam.detection_rate_hz == 0
        rest = DetectionRest(cam.still_threshold, cam.rest_after_s, 1.0 / cam.rest_detection_rate_hz)
        never_rests = cam.rest_detection_rate_hz >= cam.detection_hz  # no thumbnails either
        try:
            async for frame in capture.frames("camera: %d frames captured, %d taken, %d dropped (detection behind)"):
                now = time.monotonic()
                stamp, image = frame
                if every_frame or now + early >= next_detection:  # else passed over: detection_rate_hz
                    # on the schedule (the rate holds on average), or from now after a stall
                    next_detection = max(next_detection + detection_period, now)
                    if never_rests or rest.search(thumbnail(image), now + early):  # else resting: still picture
                        found = await asyncio.to_thread(detector.detect, image)
                        landmarks.put(m.Landmarks(stamp=stamp, landmarks=found))
                if now >= next_image:
                    next_image = now + image_period
                    images.put(await asyncio.to_thread(small.of, frame))
        finally:
            await capture.close()


if __name__ == "__main__":
    run(main)
