"""The camera model: intrinsics (from a calibration file or nominal) and the mounting on the robot.

Frames used here (all right-handed):

* **world**: x, y on the floor, z up (the world map's frame).
* **robot**: origin at the robot's centre on the floor, x forward, y left, z up.
* **camera** (OpenCV's): origin at the lens, x right, y down, z forward along the optical axis.

The camera looks horizontally (no pitch or roll); ``camera.mount_yaw`` turns it
about the robot's z axis. The simulator's renderer and the camera service both
use this module, so what the simulator draws is what the detector measures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..config import Camera
from ..errors import ConfigError


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole camera with lens distortion, for images of ``width`` x ``height`` pixels."""

    camera_matrix: np.ndarray
    """3x3 [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], pixels."""
    dist_coeffs: np.ndarray
    """OpenCV distortion coefficients (k1, k2, p1, p2[, k3, ...]); zeros = no distortion."""
    width: int
    height: int

    @classmethod
    def nominal(cls, focal_px: float, width: int, height: int) -> Intrinsics:
        """An ideal camera: square pixels, principal point in the image centre, no distortion."""
        k = np.array([[focal_px, 0.0, (width - 1) / 2], [0.0, focal_px, (height - 1) / 2], [0, 0, 1]])
        return cls(k, np.zeros(5), width, height)

    @classmethod
    def from_config(cls, camera: Camera) -> Intrinsics:
        """The calibration file ``camera.calibration`` if set, else nominal from ``camera.focal_px``."""
        if camera.calibration:
            return load_calibration(camera.calibration, camera.width, camera.height)
        if camera.focal_px <= 0:
            raise ConfigError(f"camera.focal_px: must be > 0 pixels, got {camera.focal_px}")
        return cls.nominal(camera.focal_px, camera.width, camera.height)

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same lens for the frame resized to ``width`` x ``height`` (as the camera resizes it
        for ``camera/image`` and the web API): focal lengths scale with the size; the principal
        point too, about pixel centres (OpenCV's pixel (0, 0) is the centre of the first pixel,
        so the image's left edge is at -0.5); distortion is in normalised coordinates, unchanged."""
        sx, sy = width / self.width, height / self.height
        k = self.camera_matrix.copy()
        k[0, 0], k[0, 1], k[0, 2] = k[0, 0] * sx, k[0, 1] * sx, (k[0, 2] + 0.5) * sx - 0.5
        k[1, 1], k[1, 2] = k[1, 1] * sy, (k[1, 2] + 0.5) * sy - 0.5
        return Intrinsics(k, self.dist_coeffs.copy(), width, height)


def load_calibration(path: str | Path, width: int, height: int) -> Intrinsics:
    """Read an OpenCV FileStorage file (YAML or JSON) written by a calibration (docs/camera.md).

    Required nodes: ``camera_matrix`` (3x3), ``dist_coeffs`` (4, 5, 8, 12 or 14 numbers),
    ``image_width`` and ``image_height`` (must equal the configured capture size:
    a calibration only holds for the resolution it was made at).
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: no such calibration file (camera.calibration)")
    k, d, w, h = read_storage(p, matrices=("camera_matrix", "dist_coeffs"), numbers=("image_width", "image_height"))
    if k is None or k.shape != (3, 3) or not np.all(np.isfinite(k)):
        raise ConfigError(f"{p}: camera_matrix: expected a 3x3 matrix of finite numbers")
    if k[0, 0] <= 0 or k[1, 1] <= 0 or k[2, 2] != 1:
        raise ConfigError(f"{p}: camera_matrix: fx and fy must be > 0 and the last element 1")
    if d is None or d.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(d)):
        raise ConfigError(f"{p}: dist_coeffs: expected 4, 5, 8, 12 or 14 finite numbers")
    if (int(w), int(h)) != (width, height):
        raise ConfigError(
            f"{p}: image_width/image_height: calibrated at {int(w)}x{int(h)}, "
            f"but the camera captures {width}x{height} (camera.width, camera.height)"
        )
    return Intrinsics(k.astype(np.float64), d.reshape(-1).astype(np.float64), width, height)


def read_storage(path: Path, *, matrices: tuple[str, ...], numbers: tuple[str, ...]) -> list:
    """The nodes of an OpenCV FileStorage file (YAML or JSON): the ``matrices`` (None for one that is
    missing), then the ``numbers`` (0.0 for one that is missing); `ConfigError` naming the file if
    OpenCV cannot read it."""
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise ConfigError(f"{path}: not an OpenCV YAML/JSON file: {exc.err}") from None
    try:
        return [fs.getNode(name).mat() for name in matrices] + [fs.getNode(name).real() for name in numbers]
    finally:
        fs.release()


@dataclass(frozen=True)
class MarkerInset:
    """How far inside a marker's black square the detector puts its corners, px: ``px + px2 / side``
    for a marker ``side`` pixels wide (measured by `icefloe calibrate` on a ChArUco board's markers;
    docs/camera.md). Left uncorrected, the corners' inset makes every range long: about 2 x inset /
    side, 1.5 % for a marker 25 px wide."""

    px: float = 0.0
    """The part that does not depend on the marker's size, px."""
    px2: float = 0.0
    """The part that shrinks as the marker grows in the picture, px² (px at a side of 1 px)."""

    def at(self, side_px: float) -> float:
        """The inset of a marker ``side_px`` pixels wide, px."""
        return self.px + self.px2 / max(side_px, 1.0)

    def undo(self, quad: np.ndarray) -> np.ndarray:
        """The detected corners (4 x 2 px, in order round the square) moved out by the inset: each
        edge moved out along its normal, each corner where two moved edges meet."""
        if not (self.px or self.px2):
            return quad
        q = np.asarray(quad, dtype=float).reshape(4, 2)
        edges = np.roll(q, -1, axis=0) - q                       # edge i from corner i to corner i + 1
        side = float(np.linalg.norm(edges, axis=1).mean())
        normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1) / np.linalg.norm(edges, axis=1)[:, None]
        inward = ((q.mean(axis=0) - (q + edges / 2)) * normals).sum(axis=1) > 0
        normals[inward] *= -1                                     # each one outward
        inset = self.at(side)
        out = q.copy()
        for i in range(4):  # corner i is where edge i - 1 ends and edge i starts
            n = np.array([normals[i - 1], normals[i]])
            if abs(np.linalg.det(n)) > 1e-6:
                out[i] = q[i] + np.linalg.solve(n, [inset, inset])
        return out


@dataclass(frozen=True)
class CameraCalibration:
    """What a calibration file holds besides the intrinsics (the nodes `icefloe calibrate` adds)."""

    inset: MarkerInset = MarkerInset()
    """The marker detector's corner inset (node ``marker_corner_inset``: px, px²)."""
    latency_s: float = 0.0
    """From a frame's exposure to its arrival with its stamp, s (node ``capture_latency_s``): the camera
    service takes it off every frame's stamp."""


def load_extras(path: str | Path) -> CameraCalibration:
    """The `CameraCalibration` nodes of a calibration file (each 0 when missing: files written before
    them stay good); `ConfigError` for a value that is not a finite number, or a negative latency."""
    p = Path(path)
    inset, latency = read_storage(p, matrices=("marker_corner_inset",), numbers=("capture_latency_s",))
    values = [0.0, 0.0] if inset is None else [float(v) for v in np.asarray(inset).ravel()]
    if len(values) != 2 or not all(np.isfinite(values)):
        raise ConfigError(f"{p}: marker_corner_inset: expected two finite numbers (px, px²)")
    if not (np.isfinite(latency) and 0.0 <= latency < 2.0):
        raise ConfigError(f"{p}: capture_latency_s: expected seconds in [0, 2), got {latency}")
    return CameraCalibration(MarkerInset(*values), float(latency))


def calibration_extras(camera: Camera) -> CameraCalibration:
    """The camera's `CameraCalibration`: from its calibration file, none without one."""
    return load_extras(camera.calibration) if camera.calibration else CameraCalibration()


def save_calibration(path: str | Path, intrinsics: Intrinsics, rms_px: float | None = None,
                     extras: CameraCalibration | None = None) -> None:
    """Write a calibration file in the format `load_calibration` (and `load_extras`) reads."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    try:
        fs.write("image_width", intrinsics.width)
        fs.write("image_height", intrinsics.height)
        fs.write("camera_matrix", intrinsics.camera_matrix)
        fs.write("dist_coeffs", intrinsics.dist_coeffs.reshape(1, -1))
        if rms_px is not None:
            fs.write("rms_reprojection_error_px", rms_px)
        if extras is not None:
            fs.write("marker_corner_inset", np.array([[extras.inset.px, extras.inset.px2]]))
            fs.write("capture_latency_s", extras.latency_s)
    finally:
        fs.release()


@dataclass(frozen=True)
class Mount:
    """Where the camera sits on the robot (``camera.mount_*``)."""

    x: float
    """Ahead of the robot's centre, m."""
    y: float
    """Left of the robot's centre, m."""
    z: float
    """Height of the lens above the floor, m."""
    yaw: float
    """Heading of the optical axis relative to the robot's, rad, CCW."""

    @classmethod
    def from_config(cls, camera: Camera) -> Mount:
        return cls(camera.mount_x, camera.mount_y, camera.mount_z, camera.mount_yaw)

    def robot_from_camera(self) -> np.ndarray:
        """3x3 rotation taking camera-frame vectors to robot-frame vectors."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        # Columns: where the camera's x (right), y (down) and z (forward) axes point on the robot.
        return np.array([[s, 0.0, c], [-c, 0.0, s], [0.0, -1.0, 0.0]])

    def to_robot(self, p_camera: np.ndarray) -> np.ndarray:
        """A point in the camera frame (m) → the same point in the robot frame (m)."""
        return self.robot_from_camera() @ np.asarray(p_camera, dtype=float) + [self.x, self.y, self.z]


def range_bearing(p_robot: np.ndarray) -> tuple[float, float]:
    """Range (m) and bearing (rad, CCW from the robot's heading) of a robot-frame point.

    Both are measured in the floor plane from the robot's centre: a 2-D localizer
    wants the horizontal distance, and the height of a marker does not change it.
    """
    return math.hypot(p_robot[0], p_robot[1]), math.atan2(p_robot[1], p_robot[0])
