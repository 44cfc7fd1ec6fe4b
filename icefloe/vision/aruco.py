"""ArUco dictionaries by name, as the configs give them (``camera.dictionary``, ``overhead.dictionary``), and
the robot camera's marker detector (the camera service's, and the one `icefloe calibrate` measures)."""

from __future__ import annotations

import cv2

from ..errors import ConfigError


def aruco_dictionary(name: str) -> int:
    """OpenCV's id of a predefined ArUco dictionary (``camera.dictionary``, e.g. "DICT_4X4_50")."""
    value = getattr(cv2.aruco, name, None) if name.startswith("DICT_") else None
    if not isinstance(value, int):
        raise ConfigError(f"camera.dictionary: {name!r} is not an OpenCV ArUco dictionary (e.g. DICT_4X4_50)")
    return value


def robot_detector(dictionary: str) -> cv2.aruco.ArucoDetector:
    """The robot camera's ArUco detector for ``dictionary`` (a name, e.g. "DICT_4X4_50"): the camera
    service finds its markers with it, and `icefloe calibrate` measures how far inside the black square
    it puts their corners (`icefloe.vision.geometry.MarkerInset`)."""
    params = cv2.aruco.DetectorParameters()
    # Sub-pixel corners with a small window: a 12 cm marker 2 m away is only 30 px wide, so each
    # cell is 5 px and OpenCV's default window (5 px) reaches into the neighbouring cells. OpenCV
    # >= 4.7 also caps the window at relativeCornerRefinmentWinSize (0.3) x the cell size, so it
    # is 1-2 px here. The corners land 0.1-0.25 px inside the square (more for smaller markers):
    # ranges 0.3-1.5 % long, unless the calibration's inset moves them out (docs/camera.md).
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementWinSize = 3
    params.cornerRefinementMinAccuracy = 0.01
    params.cornerRefinementMaxIterations = 100
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(aruco_dictionary(dictionary)), params)
