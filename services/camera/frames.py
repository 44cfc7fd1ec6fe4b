"""The frames HTTP clients get: JPEGs of ``camera.image_width`` x ``image_height``, and their intrinsics.

* `Frames` encodes the latest frame at that size once, however many ask for it
  (``camera/image`` a few times a second, ``camera/frame`` queries, ``camera/frames``); the
  camera's ``camera/snapshot`` uses another, at the capture size. A burst of queries
  costs one JPEG per frame, not one per query.
* ``camera/frames`` carries every captured frame, but only while something subscribes to it
  (Zenoh's matching status): the web API subscribes while an HTTP client watches
  ``/camera/get``, so an unwatched camera spends nothing on it.
* `camera_info` is the camera's calibration (made at the capture size) scaled to that size.
"""

from __future__ import annotations

import threading

import cv2
import numpy as np

from icefloe.config import Camera
from icefloe.schemas import messages as m
from icefloe.vision.geometry import Intrinsics
from icefloe.vision.sources import BadFrame, Frame


def jpeg(image: np.ndarray, quality: int) -> bytes:
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise BadFrame("JPEG encoding failed")
    return data.tobytes()


class Frames:
    """The latest frame as a JPEG of one size, encoded once: thread-safe (the capture thread and
    the event loop's workers both ask).

    By default the small frames of HTTP clients (``camera.image_width`` x ``image_height``, at
    ``camera.jpeg_quality``); ``full=True``: the capture size, at ``quality``."""

    def __init__(self, camera: Camera, *, full: bool = False, quality: int | None = None) -> None:
        self.width, self.height = (camera.width, camera.height) if full else (camera.image_width, camera.image_height)
        self.quality = camera.jpeg_quality if quality is None else quality
        self._lock = threading.Lock()
        self._frame: Frame | None = None
        self._image: m.Image | None = None

    def of(self, frame: Frame) -> m.Image:
        """``frame`` resized and encoded; the same object again for the same frame.

        Encoded under the lock: whoever asks while it is being encoded waits for that JPEG
        rather than making one more (32 snapshot queries at once were 32 encodings of one frame)."""
        with self._lock:
            if frame is not self._frame or self._image is None:
                stamp, image = frame
                if image.shape[1] != self.width or image.shape[0] != self.height:
                    image = cv2.resize(image, (self.width, self.height), interpolation=cv2.INTER_AREA)
                self._image = m.Image(stamp=stamp, width=self.width, height=self.height,
                                      data=jpeg(image, self.quality))
                self._frame = frame
            return self._image


def camera_info(camera: Camera, intrinsics: Intrinsics, latency_s: float = 0.0) -> m.CameraInfo:
    """``camera/info``: ``intrinsics`` (at the capture size) for the ``image_width`` x ``image_height`` frames,
    and the capture latency taken off the stamps."""
    small = intrinsics.scaled(camera.image_width, camera.image_height)
    k = small.camera_matrix
    return m.CameraInfo(
        width=small.width, height=small.height,
        fx=float(k[0, 0]), fy=float(k[1, 1]), cx=float(k[0, 2]), cy=float(k[1, 2]),
        camera_matrix=[float(v) for v in k.ravel()], dist_coeffs=[float(v) for v in small.dist_coeffs.ravel()],
        capture_width=intrinsics.width, capture_height=intrinsics.height,
        source=camera.calibration or "nominal", capture_latency_s=latency_s,
    )
