"""Where frames come from, chosen by ``camera.source``; the service cannot tell them apart.

Each source has ``read() -> (stamp_ns, BGR image)``, blocking until the next frame
(called on the capture thread), and ``close()``. A source that fails raises
`SourceError`; the service logs it, closes the source and opens it again later.

* ``"sim"``: renders the simulated world from the robot's true pose (``sim/truth``).
* ``"picamera2"``: the Raspberry Pi camera.
* ``"v4l2:<index or /dev/videoN>"``: any USB/V4L2 camera through OpenCV.
* a folder of images, or a video file: replays recorded data, in a loop.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from icefloe.config import RobotConfig
from icefloe.errors import IcefloeError
from icefloe.schemas import messages as m

from .detection import BadFrame


class SourceError(IcefloeError):
    """The camera is missing or stopped delivering frames."""


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


class SimSource:
    """Frames rendered from the latest true pose, which the service hands over with `set_truth`."""

    def __init__(self, config: RobotConfig) -> None:
        from icefloe.sim.camera import CameraRenderer, true_intrinsics  # the simulator only where it is used
        from icefloe.worldmap import load_world

        from .geometry import Mount

        # The simulated lens is [sim.lens], not what [camera] believes: calibrating must find it.
        self.renderer = CameraRenderer(load_world(config.sim.world), true_intrinsics(config),
                                       Mount.from_config(config.camera), config.camera.dictionary)
        self.pace = Paced(config.camera.fps)
        self._truth: m.Truth | None = None
        self._lock = threading.Lock()

    def set_truth(self, truth: m.Truth) -> None:
        with self._lock:
            self._truth = truth

    def read(self) -> tuple[int, np.ndarray]:
        self.pace.wait()
        with self._lock:
            truth = self._truth
        if truth is None:
            raise SourceError("no sim/truth yet: is the simulator running?")
        image, _ = self.renderer.render(truth.x, truth.y, truth.theta)
        return truth.stamp, image  # the frame shows the world at the truth's time

    def close(self) -> None:
        pass


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


def open_source(config: RobotConfig) -> Source:
    """The source named by ``camera.source``; `SourceError` if it cannot be opened now."""
    cam = config.camera
    spec = cam.source
    if spec == "sim":
        return SimSource(config)
    if spec == "picamera2":
        return Picamera2Source(cam.width, cam.height)
    if spec.startswith("v4l2:"):
        target = spec.removeprefix("v4l2:")
        return OpenCvSource(int(target) if target.isdigit() else target, cam.width, cam.height)
    path = Path(spec).expanduser()
    if path.is_file():
        return OpenCvSource(str(path), cam.width, cam.height, loop=True)
    return FolderSource(path, cam.fps)
