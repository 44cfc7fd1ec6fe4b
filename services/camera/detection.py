"""ArUco detection and the pose of each marker, as the robot sees it.

`Detector.detect` finds the markers in a BGR frame with OpenCV's
`cv2.aruco.ArucoDetector`, moves their corners out by the inset the calibration
measured (`MarkerInset`: the detector puts them a fraction of a pixel inside the
black square, which makes every range long), solves each marker's pose with
`cv2.solvePnP(..., SOLVEPNP_IPPE_SQUARE)` from its printed size (from the world
map, or `camera.marker_size` for ids the map does not know), and turns it into
a `Landmark`: range and bearing from the robot's centre (camera mount applied),
the corners in pixels (as detected) and the full pose in the camera frame.
"""

from __future__ import annotations

import cv2
import numpy as np

from icefloe.config import RobotConfig
from icefloe.errors import ConfigError
from icefloe.schemas import messages as m
from icefloe.vision.aruco import robot_detector
from icefloe.vision.geometry import Intrinsics, MarkerInset, Mount, calibration_extras, range_bearing
from icefloe.worldmap import load_world


class Detector:
    def __init__(self, dictionary: str, intrinsics: Intrinsics, mount: Mount,
                 sizes: dict[int, float], default_size: float, inset: MarkerInset | None = None) -> None:
        """``sizes``: printed side of the black square per marker id, m. ``inset``: how far inside
        the square the detector's corners are (the calibration's; none: as detected)."""
        self._aruco = robot_detector(dictionary)
        self.k, self.dist = intrinsics.camera_matrix, intrinsics.dist_coeffs
        self.width, self.height = intrinsics.width, intrinsics.height
        self.mount = mount
        self.sizes, self.default_size = sizes, default_size
        self.inset = inset or MarkerInset()

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
            ok, rvec, tvec = cv2.solvePnP(self._object_points(size), self.inset.undo(quad.reshape(4, 2)), self.k,
                                          self.dist, flags=cv2.SOLVEPNP_IPPE_SQUARE)
            if not ok or not (np.all(np.isfinite(tvec)) and np.all(np.isfinite(rvec))):
                continue  # a degenerate quad: no pose, rather than NaN on the bus
            position = tvec.ravel()
            rng, bearing = range_bearing(self.mount.to_robot(position))
            found.append(m.Landmark(id=int(marker_id), range=rng, bearing=bearing,
                                    corners=[float(v) for v in quad.ravel()],
                                    position=[float(v) for v in position],
                                    rotation=[float(v) for v in rvec.ravel()]))
        return found


def make_detector(config: RobotConfig) -> Detector:
    cam = config.camera
    try:
        world = load_world(config.localizer.world)
        sizes = world.sizes()  # markers, and the faces of marker blocks
    except ConfigError:
        sizes = {}  # no map: every marker is taken to have camera.marker_size
    return Detector(cam.dictionary, Intrinsics.from_config(cam), Mount.from_config(cam), sizes, cam.marker_size,
                    calibration_extras(cam).inset)
