"""The capture loop the camera service and the lab's localizer share (icefloe/vision/capture.py), and
the sources it opens (icefloe/vision/sources.py), with fake cameras shaped like the real ones."""

from __future__ import annotations

import asyncio
import logging
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import wait_for

from icefloe.logs import LimitedLog
from icefloe.vision.capture import Capture, LatestFrame
from icefloe.vision.sources import BadFrame, FolderSource, OpenCvSource, SourceError, check_frame, open_source

W, H = 64, 48


class FakeCamera:
    """A source (``read``, ``close``) that gives the frames it is handed, then fails as it is told."""

    def __init__(self, script: list[object]) -> None:
        self.script = script
        """Each read takes the next: an image to give, or an exception to raise."""
        self.reads = 0
        self.closed = False
        self.ready = threading.Semaphore(0)
        self.free = False
        """Reads no longer wait for the test (it is ending)."""

    def read(self) -> tuple[int, np.ndarray]:
        if not self.free:
            self.ready.acquire()  # the test lets each read through
        item = self.script[min(self.reads, len(self.script) - 1)]
        self.reads += 1
        if isinstance(item, Exception):
            raise item
        return self.reads, item  # type: ignore[return-value]

    def close(self) -> None:
        self.closed = True


def image(value: int) -> np.ndarray:
    return np.full((H, W, 3), value, np.uint8)


def test_latest_frame_keeps_the_newest_and_counts_the_overwritten() -> None:
    slot = LatestFrame()
    assert slot.take(0.0) is None
    for stamp in (1, 2, 3):
        slot.put((stamp, image(stamp)))
    frame = slot.take(0.0)
    assert frame is not None and frame[0] == 3
    assert (slot.captured, slot.dropped) == (3, 2)
    assert slot.take(0.0) is None and slot.latest is not None and slot.latest[0] == 3  # kept for snapshots


def test_check_frame_names_what_is_wrong() -> None:
    assert check_frame(image(1), W, H) is not None
    for bad, message in ((None, "empty"), (np.zeros((H, W), np.float32), "float32"), (image(1)[:10], "expected 48x64")):
        with pytest.raises(BadFrame, match=message):
            check_frame(bad, W, H)


async def test_capture_skips_bad_frames_and_reopens_a_camera_that_failed(caplog) -> None:
    log = logging.getLogger("icefloe.test-capture")
    cameras: list[FakeCamera] = []
    scripts = [[image(1), image(0)[:10], SourceError("unplugged")], [image(2)]]

    def opener() -> FakeCamera:
        cameras.append(FakeCamera(scripts[len(cameras)]))
        return cameras[-1]

    seen: list[int] = []
    capture = Capture("fake camera", "fake:0", opener, W, H, log=log, limited=LimitedLog(log),
                      thread_name="test-capture", on_frame=lambda f: seen.append(f[0]), retry_s=0.01)
    caplog.set_level(logging.INFO, logger=log.name)
    capture.start()
    frames = capture.frames("%d captured, %d taken, %d dropped")
    try:
        await wait_for(lambda: cameras, timeout=10)
        cameras[0].ready.release()
        stamp, got = await asyncio.wait_for(anext(frames), 10)
        assert stamp == 1 and got[0, 0, 0] == 1 and capture.source is cameras[0]
        cameras[0].ready.release()  # a frame of the wrong size: skipped, the camera stays open
        await wait_for(lambda: "bad frame skipped" in caplog.text, timeout=10)
        cameras[0].ready.release()  # the camera fails: closed, opened again after retry_s
        await wait_for(lambda: len(cameras) == 2, timeout=10)
        assert cameras[0].closed and "fake camera 'fake:0' failed: unplugged; retrying" in caplog.text
        cameras[1].ready.release()
        stamp, got = await asyncio.wait_for(anext(frames), 10)
        assert got[0, 0, 0] == 2 and capture.source is cameras[1]
        assert seen == [1, 1] and capture.taken == 2  # on_frame saw the good frames, at once
    finally:
        for camera in cameras:
            camera.free = True
            camera.ready.release()
        await frames.aclose()
        await capture.close()
    assert cameras[-1].closed


def test_open_source_picks_the_source_the_setting_names(tmp_path: Path) -> None:
    sim = FakeCamera([image(1)])
    assert open_source("sim", W, H, 10.0, setting="camera.source", sim=lambda: sim) is sim
    assert isinstance(open_source(str(tmp_path), W, H, 10.0, setting="camera.source", sim=lambda: sim), FolderSource)
    video = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (W, H))
    for value in (10, 20):
        writer.write(image(value))
    writer.release()
    source = open_source(str(video), W, H, 10.0, setting="camera.source", sim=lambda: sim)
    try:
        assert isinstance(source, OpenCvSource) and source.read()[1].shape == (H, W, 3)
    finally:
        source.close()
    with pytest.raises(SourceError, match=r"overhead\.source: '/nowhere' is no camera, image folder or video file"):
        open_source("/nowhere", W, H, 10.0, setting="overhead.source", sim=lambda: sim)
