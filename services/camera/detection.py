"""ArUco detection and the pose of each marker, as the robot sees it.

`Detector.detect` finds the markers in a BGR frame with OpenCV's
`cv2.aruco.ArucoDetector`, solves each marker's pose with
`cv2.solvePnP(..., SOLVEPNP_IPPE_SQUARE)` from its printed size (from the world
map, or `camera.marker_size` for ids the map does not know), and turns it into
a `Landmark`: range and bearing from the robot's centre (camera mount applied),
the corners in pixels and the full pose in the camera frame.
"""

from __future__ import annotations

import cv2
import numpy as np

from icefloe.errors import ConfigError, IcefloeError
from icefloe.schemas import messages as m

from .geometry import Intrinsics, Mount, range_bearing


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


def aruco_dictionary(name: str) -> int:
    """OpenCV's id of a predefined ArUco dictionary (``camera.dictionary``, e.g. "DICT_4X4_50")."""
    value = getattr(cv2.aruco, name, None) if name.startswith("DICT_") else None
    if not isinstance(value, int):
        raise ConfigError(f"camera.dictionary: {name!r} is not an OpenCV ArUco dictionary (e.g. DICT_4X4_50)")
    return value


class Detector:
    def __init__(self, dictionary: str, intrinsics: Intrinsics, mount: Mount,
                 sizes: dict[int, float], default_size: float) -> None:
        """``sizes``: printed side of the black square per marker id, m."""
        params = cv2.aruco.DetectorParameters()
        # Sub-pixel corners with a small window: a 12 cm marker 2 m away is only 30 px wide, so each
        # cell is 5 px and OpenCV's default window (5 px) reaches into the neighbouring cells. OpenCV
        # >= 4.7 also caps the window at relativeCornerRefinmentWinSize (0.3) x the cell size, so it
        # is 1-2 px here. The corners land ~0.24 px inside the square: ranges ~0.9 % long (docs/camera.md).
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        params.cornerRefinementWinSize = 3
        params.cornerRefinementMinAccuracy = 0.01
        params.cornerRefinementMaxIterations = 100
        self._aruco = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(aruco_dictionary(dictionary)),
                                              params)
        self.k, self.dist = intrinsics.camera_matrix, intrinsics.dist_coeffs
        self.width, self.height = intrinsics.width, intrinsics.height
        self.mount = mount
        self.sizes, self.default_size = sizes, default_size

    def _object_points(self, size: float) -> np.ndarray:
        h = size / 2  # corner order of IPPE_SQUARE: top-left, top-right, bottom-right, bottom-left
        return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])

    def detect(self, image: np.ndarray) -> list[m.Landmark]:
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        corners, ids, _ = self._aruco.detectMarkers(gray)
        if ids is None:
            return []
        found = []
        for quad, marker_id in zip(corners, ids.ravel(), strict=True):
            size = self.sizes.get(int(marker_id), self.default_size)
            ok, rvec, tvec = cv2.solvePnP(self._object_points(size), quad.reshape(4, 2), self.k, self.dist,
                                          flags=cv2.SOLVEPNP_IPPE_SQUARE)
            if not ok or not (np.all(np.isfinite(tvec)) and np.all(np.isfinite(rvec))):
                continue  # a degenerate quad: no pose, rather than NaN on the bus
            position = tvec.ravel()
            rng, bearing = range_bearing(self.mount.to_robot(position))
            found.append(m.Landmark(id=int(marker_id), range=rng, bearing=bearing,
                                    corners=[float(v) for v in quad.ravel()],
                                    position=[float(v) for v in position],
                                    rotation=[float(v) for v in rvec.ravel()]))
        return found
