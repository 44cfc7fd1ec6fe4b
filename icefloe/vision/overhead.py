"""The overhead camera's geometry: where it hangs, and what a pixel on it means on the floor.

Frames (right-handed): **world** as the world map's (x, y on the floor, z up; the frame of
``sim/truth`` and of the localizer), and OpenCV's **camera** frame (x right, y down, z along the
optical axis). `CameraPose` is the camera's pose in the world (``camera_from_world``: a point p of
the world is ``R @ p + t`` in the camera frame, as `cv2.solvePnP` gives it).

A flat square seen from above (a floor marker, a robot's top marker) is described by its centre,
its height, its side and ``yaw``, the direction its top edge points: its corners, in ArUco's order
(top-left, top-right, bottom-right, bottom-left as printed), are `flat_square_corners`. A robot's
heading is the direction its top marker's top edge points.

The simulator's overhead renderer and the localizer both use this module, so what the simulator
draws is what the localizer measures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..errors import ConfigError
from .geometry import Intrinsics, read_storage


@dataclass(frozen=True)
class CameraPose:
    """Where the camera is: ``camera_from_world`` as a rotation matrix and a translation (m)."""

    rotation: np.ndarray
    """3x3, camera_from_world."""
    translation: np.ndarray
    """3, m: the world's origin in the camera frame."""

    @classmethod
    def looking_down(cls, x: float, y: float, z: float, yaw: float = 0.0, tilt: float = 0.0) -> CameraPose:
        """A camera at (x, y, z) looking straight down (tilted by ``tilt`` rad about its horizontal
        axis), the top of its picture pointing along ``yaw`` on the floor."""
        c, s = math.cos(yaw), math.sin(yaw)
        # Columns: the camera's x (picture right), y (picture down), z (optical axis) in the world.
        world_from_camera = np.array([[s, -c, 0.0], [-c, -s, 0.0], [0.0, 0.0, -1.0]]).T
        ct, st = math.cos(tilt), math.sin(tilt)
        tilt_about_x = np.array([[1.0, 0.0, 0.0], [0.0, ct, -st], [0.0, st, ct]])
        world_from_camera = world_from_camera @ tilt_about_x
        rotation = world_from_camera.T
        return cls(rotation, -rotation @ np.array([x, y, z], dtype=float))

    @classmethod
    def from_rvec(cls, rvec: np.ndarray, tvec: np.ndarray) -> CameraPose:
        return cls(cv2.Rodrigues(np.asarray(rvec, dtype=float).reshape(3))[0], np.asarray(tvec, dtype=float).reshape(3))

    @property
    def rvec(self) -> np.ndarray:
        return cv2.Rodrigues(self.rotation)[0].reshape(3)

    @property
    def lens(self) -> np.ndarray:
        """The lens's position in the world, m."""
        return -self.rotation.T @ self.translation

    @property
    def height(self) -> float:
        """The lens's height above the floor, m."""
        return float(self.lens[2])

    def to_camera(self, points_world: np.ndarray) -> np.ndarray:
        """World points (n, 3) → camera frame (n, 3)."""
        return np.asarray(points_world, dtype=float) @ self.rotation.T + self.translation


def flat_square_corners(x: float, y: float, z: float, yaw: float, half: float) -> np.ndarray:
    """World corners (4x3, m) of a flat square seen from above, centred at (x, y, z), its top
    edge pointing along ``yaw``: top-left, top-right, bottom-right, bottom-left as printed."""
    up = np.array([math.cos(yaw), math.sin(yaw), 0.0]) * half
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0]) * half
    centre = np.array([x, y, z], dtype=float)
    return np.array([centre - right + up, centre + right + up, centre + right - up, centre - right - up])


SQUARE = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, -1.0], [-1.0, 1.0]])
"""The corners of a flat square in its own frame (forward = its top edge, left), in half sides."""


def project(intrinsics: Intrinsics, pose: CameraPose, points_world: np.ndarray) -> np.ndarray:
    """World points (n, 3) → pixels (n, 2), the lens's distortion included."""
    pixels, _ = cv2.projectPoints(np.asarray(points_world, dtype=np.float64).reshape(-1, 1, 3), pose.rvec,
                                  pose.translation, intrinsics.camera_matrix, intrinsics.dist_coeffs)
    return pixels.reshape(-1, 2)


UNDISTORT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-9)
"""OpenCV's default undistortion stops after 5 iterations: millimetres off on the floor in the
corners of a wide lens. This iterates to convergence."""


def undistort(intrinsics: Intrinsics, pixels: np.ndarray) -> np.ndarray:
    """Pixels (n, 2) → normalized image coordinates (n, 2) of an ideal pinhole (distortion undone)."""
    points = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    k, dist = intrinsics.camera_matrix, intrinsics.dist_coeffs
    if not np.any(dist):
        return cv2.undistortPoints(points, k, dist).reshape(-1, 2)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
        return cv2.undistortPointsIter(points, k, dist, None, None, UNDISTORT).reshape(-1, 2)
    return cv2.undistortPoints(points, k, dist, R=None, P=None, criteria=UNDISTORT).reshape(-1, 2)  # OpenCV 5


def to_plane(intrinsics: Intrinsics, pose: CameraPose, pixels: np.ndarray, z: float) -> np.ndarray:
    """Pixels (n, 2) → the world points (n, 3) they see on the horizontal plane at height ``z``
    (the floor: 0; a robot's top marker: its height). NaN for a pixel whose ray misses it."""
    normalized = undistort(intrinsics, pixels)
    rays = np.column_stack([normalized, np.ones(len(normalized))]) @ pose.rotation  # world directions
    lens = pose.lens
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = (z - lens[2]) / rays[:, 2]
    scale[~(scale > 0)] = np.nan
    return lens + rays * scale[:, None]


def fit_square(corners_world: np.ndarray) -> tuple[float, float, float, float, float]:
    """The flat square that best fits four corners (4x3, ArUco order) measured on its plane:
    centre x, y (m), heading (rad, where its top edge points), side (m), and the RMS distance of
    the corners from that square (m): how square what was seen was."""
    points = np.asarray(corners_world, dtype=float)[:, :2]
    centre = points.mean(axis=0)
    d = points - centre
    # The rotation that best takes the model square onto the corners (2-D Procrustes).
    cross = float(np.sum(SQUARE[:, 0] * d[:, 1] - SQUARE[:, 1] * d[:, 0]))
    dot = float(np.sum(SQUARE[:, 0] * d[:, 0] + SQUARE[:, 1] * d[:, 1]))
    theta = math.atan2(cross, dot)
    half = math.hypot(cross, dot) / float(np.sum(SQUARE**2))
    c, s = math.cos(theta), math.sin(theta)
    model = SQUARE @ np.array([[c, s], [-s, c]]) * half
    residual = float(np.sqrt(np.mean(np.sum((d - model) ** 2, axis=1))))
    return float(centre[0]), float(centre[1]), theta, 2 * half, residual


def save_pose(path: str | Path, pose: CameraPose, intrinsics: Intrinsics, rms_px: float, rms_floor_m: float) -> None:
    """Write the camera's pose (OpenCV YAML: ``rvec``, ``tvec`` camera_from_world, m) with the fit's figures."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    try:
        fs.write("image_width", intrinsics.width)
        fs.write("image_height", intrinsics.height)
        fs.write("rvec", pose.rvec.reshape(3, 1))
        fs.write("tvec", pose.translation.reshape(3, 1))
        fs.write("rms_reprojection_error_px", float(rms_px))
        fs.write("rms_floor_error_m", float(rms_floor_m))
    finally:
        fs.release()


def load_pose(path: str | Path, width: int, height: int) -> CameraPose:
    """Read a pose file `save_pose` wrote; `ConfigError` naming the file and the node otherwise."""
    p = Path(path).expanduser()
    if not p.is_file():
        raise ConfigError(f"{p}: no such camera pose file (overhead.pose): run `icefloe extloc calibrate`")
    rvec, tvec, w, h = read_storage(p, matrices=("rvec", "tvec"), numbers=("image_width", "image_height"))
    for name, value in (("rvec", rvec), ("tvec", tvec)):
        if value is None or value.size != 3 or not np.all(np.isfinite(value)):
            raise ConfigError(f"{p}: {name}: expected 3 finite numbers")
    if (int(w), int(h)) != (width, height):
        raise ConfigError(f"{p}: image_width/image_height: found at {int(w)}x{int(h)}, but the camera "
                          f"captures {width}x{height} (overhead.width, overhead.height)")
    return CameraPose.from_rvec(rvec, tvec)
