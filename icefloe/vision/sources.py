"""Where frames come from, chosen by a setting (``camera.source``, ``overhead.source``); the
service reading them cannot tell them apart.

Each source has ``read() -> (stamp_ns, BGR image)``, blocking until the next frame
(called on the capture thread, `icefloe.vision.capture`), and ``close()``. A source that fails
raises `SourceError`; the capture loop logs it, closes the source and opens it again later.

* ``"sim"``: the simulator's picture, rendered by a source the service brings (the robot's
  camera: `icefloe.services.camera.sources.SimSource`; the lab's overhead camera:
  `icefloe.services.extloc.sources.SimOverheadSource`).
* ``"picamera2"``: the Raspberry Pi camera.
* ``"v4l2:<index or /dev/videoN>"``: any USB/V4L2 camera through OpenCV.
* a folder of images, or a video file: replays recorded data, in a loop.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from ..errors import IcefloeError

Frame = tuple[int, np.ndarray]
"""(capture stamp, ns since the epoch; the BGR frame at the capture size)."""


class SourceError(IcefloeError):
    """The camera is missing or stopped delivering frames."""


class BadFrame(IcefloeError):
    """A frame that cannot be used: empty, wrong size, wrong type."""


def check_frame(image: object, width: int, height: int) -> np.ndarray:
    """The frame, if it is a ``height`` x ``width`` BGR (or grey) uint8 image; else `BadFrame`."""
    if not isinstance(image, np.ndarray) or image.size == 0:
        raise BadFrame("empty frame")
    if image.dtype != np.uint8:
        raise BadFrame(f"frame of {image.dtype}, expected uint8")
    if image.shape[:2] != (height, width) or image.ndim not in (2, 3):
        raise BadFrame(f"frame of shape {image.shape}, expected {height}x{width} (camera.width, camera.height)")
    return image


class Source(Protocol):
    def read(self) -> tuple[int, np.ndarray]: ...
    def close(self) -> None: ...


class Paced:
    """Sleeps to hold a frame rate (absolute deadlines, so the rate does not drift)."""

    def __init__(self, fps: float) -> None:
        self.period = 1.0 / fps
        self.next = time.monotonic()

    def wait(self) -> None:
        self.next += self.period
        delay = self.next - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        else:
            self.next = time.monotonic()  # late: do not try to catch up with a burst


class OpenCvSource:
    """A V4L2/USB camera, or a video file, through `cv2.VideoCapture`."""

    def __init__(self, target: int | str, width: int, height: int, loop: bool = False) -> None:
        self.target, self.loop = target, loop
        self.capture = cv2.VideoCapture(target)
        if not self.capture.isOpened():
            raise SourceError(f"cannot open camera {target!r}")
        if isinstance(target, int):
            self.capture.set(cv2.CAP_PROP_FRAME_WIDTH, width)
            self.capture.set(cv2.CAP_PROP_FRAME_HEIGHT, height)

    def read(self) -> tuple[int, np.ndarray]:
        ok, image = self.capture.read()
        if not ok and self.loop:
            self.capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, image = self.capture.read()
        if not ok:
            raise SourceError(f"camera {self.target!r} delivered no frame")
        return time.time_ns(), image

    def close(self) -> None:
        self.capture.release()


class FolderSource:
    """Replays the images of a folder in name order, in a loop, at ``fps``."""

    SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp")

    def __init__(self, folder: Path, fps: float) -> None:
        self.folder = folder
        self.pace = Paced(fps)
        self.index = 0

    def read(self) -> tuple[int, np.ndarray]:
        self.pace.wait()
        files = sorted(p for p in self.folder.glob("*") if p.suffix.lower() in self.SUFFIXES) \
            if self.folder.is_dir() else []
        if not files:
            raise SourceError(f"{self.folder}: no images (folder missing or empty)")
        path = files[self.index % len(files)]
        self.index += 1
        data = np.fromfile(path, dtype=np.uint8)
        image = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
        if image is None:  # one bad file is a bad frame; the next file may be fine
            raise BadFrame(f"{path}: not a readable image (corrupt or empty file)")
        return time.time_ns(), image

    def close(self) -> None:
        pass


class CameraMissing(SourceError):
    """The software of the configured camera is not installed here: waiting or restarting cannot help."""


def picamera2_class() -> type:
    """picamera2's ``Picamera2`` (Raspberry Pi OS has it, with libcamera's bindings, as apt packages only;
    the robot's venv sees them through its system site packages: docs/deploy.md)."""
    try:
        from picamera2 import Picamera2
    except ImportError as exc:  # picamera2 itself, or libcamera's bindings it imports
        raise CameraMissing(f'camera.source = "picamera2": cannot import {exc.name or "picamera2"} '
                            "(Raspberry Pi OS: sudo apt install python3-picamera2)") from None
    return Picamera2


class Picamera2Source:
    """The Raspberry Pi camera (picamera2 is imported only here)."""

    def __init__(self, width: int, height: int) -> None:
        self.camera = picamera2_class()()
        self.camera.configure(self.camera.create_video_configuration(
            main={"size": (width, height), "format": "BGR888"}))
        self.camera.start()

    def read(self) -> tuple[int, np.ndarray]:
        return time.time_ns(), self.camera.capture_array()

    def close(self) -> None:
        self.camera.stop()
        self.camera.close()


def open_source(spec: str, width: int, height: int, fps: float, *, setting: str,
                sim: Callable[[], Source]) -> Source:
    """The source ``spec`` names (the value of ``setting``, e.g. "camera.source"): ``sim()`` for
    "sim", a camera, a video file or a folder of images; `SourceError` if it cannot be opened now."""
    if spec == "sim":
        return sim()
    if spec == "picamera2":
        return Picamera2Source(width, height)
    if spec.startswith("v4l2:"):
        target = spec.removeprefix("v4l2:")
        return OpenCvSource(int(target) if target.isdigit() else target, width, height)
    path = Path(spec).expanduser()
    if path.is_file():
        return OpenCvSource(str(path), width, height, loop=True)
    if not path.is_dir():
        raise SourceError(f"{setting}: {spec!r} is no camera, image folder or video file")
    return FolderSource(path, fps)
