"""Finding the robots' top markers in an overhead picture, and the camera's pose from the floor.

`Locator.locate` finds ArUco markers with OpenCV (sub-pixel corners), takes those that are a
robot's top marker (by id), casts each corner's ray through the lens (its distortion undone)
onto the plane of the marker's height, and fits a square of the marker's printed size to the
four points: its centre is the robot's position, the direction of its top edge the robot's
heading, and how far the points are from a square (and from the printed size) says how far to
trust it (`Fix.sigma_xy`, `Fix.sigma_theta`).

`calibrate` finds the camera's pose from the floor markers of the world file: their corners'
known positions and where they are in the picture (`cv2.solvePnP`, refined with
Levenberg-Marquardt), and says how good the fit is, in pixels and in metres on the floor.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import cv2
import numpy as np

from icefloe.errors import ConfigError, IcefloeError
from icefloe.vision.aruco import aruco_dictionary
from icefloe.vision.geometry import Intrinsics
from icefloe.vision.overhead import CameraPose, fit_square, flat_square_corners, project, to_plane
from icefloe.worldmap import WorldMap

MIN_FLOOR_MARKERS = 2
"""Floor markers a calibration needs in view (each gives four corners)."""
SIGMA_PX = 0.15
"""The corners' typical error in the picture, px: the floor for a pose's uncertainty."""


class CalibrationFailed(IcefloeError):
    """Too few floor markers in view to find the camera's pose."""


@dataclass(frozen=True)
class TopMarker:
    """A robot's top marker, as its config (``[extloc]``) describes it."""

    robot: str
    marker_id: int
    size: float
    height: float


@dataclass(frozen=True)
class Fix:
    """One robot seen in one frame."""

    robot: str
    x: float
    """m, world frame."""
    y: float
    theta: float
    """rad, CCW from +x: where the marker's top edge (the robot's front) points."""
    sigma_xy: float
    """Standard deviation of x and of y, m."""
    sigma_theta: float
    """Standard deviation of theta, rad."""
    side_px: float
    """Side of the marker in the picture, px."""


def make_detector(dictionary: str) -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    # Markers seen from 2.5 m at 1280x720 are 25-30 px across: cells of 4-5 px. A small sub-pixel
    # window stays inside a cell (as the robot's camera's detector, services/camera/detection.py).
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementWinSize = 3
    params.relativeCornerRefinmentWinSize = 0.5  # OpenCV >= 4.7 caps the window at this x a cell
    params.cornerRefinementMinAccuracy = 0.01
    params.cornerRefinementMaxIterations = 100
    # Two thresholding passes (windows of 3 and 13 px) instead of three: the markers are small and
    # evenly lit, and the third pass (23 px) found nothing more in the simulator's frames, at a third
    # of the time (bench/overhead_localizer.py).
    params.adaptiveThreshWinSizeMax = 13
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(aruco_dictionary(dictionary)), params)


def find_markers(detector: cv2.aruco.ArucoDetector, image: np.ndarray) -> dict[int, np.ndarray]:
    """Marker id → its corners (4x2 px, ArUco order); a marker seen twice is left out (which is it?)."""
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    corners, ids, _ = detector.detectMarkers(gray)
    if ids is None:
        return {}
    found: dict[int, np.ndarray] = {}
    twice: set[int] = set()
    for quad, marker_id in zip(corners, ids.ravel(), strict=True):
        i = int(marker_id)
        if i in found:
            twice.add(i)
        found[i] = quad.reshape(4, 2).astype(np.float64)
    for i in twice:
        del found[i]
    return found


def dictionary_size(dictionary: str) -> int:
    """How many markers the ArUco dictionary ``overhead.dictionary`` has; `ConfigError` naming it."""
    try:
        return int(cv2.aruco.getPredefinedDictionary(aruco_dictionary(dictionary)).bytesList.shape[0])
    except ConfigError:
        raise ConfigError(f"overhead.dictionary: {dictionary!r} is not an OpenCV ArUco dictionary "
                          "(e.g. DICT_4X4_100)") from None


def top_markers(robots: list[TopMarker], world: WorldMap, dictionary: str = "DICT_4X4_100") -> dict[int, TopMarker]:
    """Id → robot; `ConfigError` for two robots with one id, a robot with a floor marker's id, or
    an id (a floor marker's too) the dictionary does not have."""
    by_id: dict[int, TopMarker] = {}
    floor = {f.id for f in world.floor_markers}
    size = dictionary_size(dictionary)
    if floor and max(floor) >= size:
        raise ConfigError(f"world {world.name}: floor marker {max(floor)} is not in {dictionary} (ids 0-{size - 1})")
    for robot in robots:
        if robot.marker_id < 0:
            raise ConfigError(f"{robot.robot}: extloc.marker_id: the robot has no top marker (set its id)")
        if robot.marker_id >= size:
            raise ConfigError(f"{robot.robot}: extloc.marker_id: {robot.marker_id} is not in {dictionary} "
                              f"(overhead.dictionary: ids 0-{size - 1})")
        if robot.marker_id in by_id:
            raise ConfigError(f"{robot.robot}: extloc.marker_id: {robot.marker_id} is robot "
                              f"{by_id[robot.marker_id].robot}'s too")
        if robot.marker_id in floor:
            raise ConfigError(f"{robot.robot}: extloc.marker_id: {robot.marker_id} is a floor marker's "
                              f"id in world {world.name}")
        by_id[robot.marker_id] = robot
    return by_id


class Locator:
    """The robots' poses in overhead pictures, for one camera (its lens and its pose)."""

    def __init__(self, dictionary: str, intrinsics: Intrinsics, pose: CameraPose,
                 robots: Mapping[int, TopMarker]) -> None:
        self.detector = make_detector(dictionary)
        self.intrinsics, self.pose, self.robots = intrinsics, pose, dict(robots)
        self.metres_per_px = pose.height / float(intrinsics.camera_matrix[0, 0])

    def locate(self, image: np.ndarray) -> list[Fix]:
        return self.fixes(find_markers(self.detector, image))

    def fixes(self, markers: Mapping[int, np.ndarray]) -> list[Fix]:
        out = []
        for marker_id, pixels in markers.items():
            robot = self.robots.get(marker_id)
            if robot is None:
                continue
            points = to_plane(self.intrinsics, self.pose, pixels, robot.height)
            if not np.all(np.isfinite(points)):
                continue
            x, y, theta, side, residual = fit_square(points)
            # How far from the printed square: the corners' own scatter, and a size that is off
            # (a marker lifted or tilted, a wrong marker_height).
            error = math.hypot(residual, abs(side - robot.size) / 2)
            floor = SIGMA_PX * (self.pose.height - robot.height) / float(self.intrinsics.camera_matrix[0, 0])
            sigma_xy = max(error / 2, floor / 2)
            sigma_theta = max(error, floor) / (robot.size / 2)
            side_px = float(np.mean(np.linalg.norm(pixels - np.roll(pixels, 1, axis=0), axis=1)))
            out.append(Fix(robot.robot, x, y, theta, sigma_xy, sigma_theta, side_px))
        return out


@dataclass(frozen=True)
class Calibration:
    pose: CameraPose
    rms_px: float
    """RMS reprojection error of the floor markers' corners, px."""
    rms_floor_m: float
    """RMS distance, on the floor, between where the corners are and where their pixels say, m."""
    worst_floor_m: float
    markers: list[int]
    """The floor markers it used."""


def floor_corners(world: WorldMap) -> dict[int, np.ndarray]:
    """Floor marker id → its black square's corners in the world (4x3, m, ArUco order)."""
    return {f.id: flat_square_corners(f.x, f.y, 0.0, f.yaw, f.size / 2) for f in world.floor_markers}


def calibrate(intrinsics: Intrinsics, world: WorldMap, markers: Mapping[int, np.ndarray]) -> Calibration:
    """The camera's pose from the floor markers seen (id → 4x2 px); `CalibrationFailed` with too few."""
    known = floor_corners(world)
    used = sorted(i for i in markers if i in known)
    if len(used) < MIN_FLOOR_MARKERS:
        raise CalibrationFailed(
            f"{len(used)} of world {world.name}'s {len(known)} floor markers in view "
            f"(ids {sorted(known)}; seen: {sorted(markers)}): at least {MIN_FLOOR_MARKERS} are needed")
    objects = np.concatenate([known[i] for i in used])
    pixels = np.concatenate([markers[i] for i in used])
    k, dist = intrinsics.camera_matrix, intrinsics.dist_coeffs
    ok, rvec, tvec = cv2.solvePnP(objects, pixels, k, dist, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise CalibrationFailed("cv2.solvePnP found no camera pose from the floor markers")
    rvec, tvec = cv2.solvePnPRefineLM(objects, pixels, k, dist, rvec, tvec)
    pose = CameraPose.from_rvec(rvec, tvec)
    if pose.height <= 0:
        raise CalibrationFailed("the camera would be under the floor: are the floor markers' positions right?")
    reprojected = project(intrinsics, pose, objects)
    rms_px = float(np.sqrt(np.mean(np.sum((reprojected - pixels) ** 2, axis=1))))
    on_floor = to_plane(intrinsics, pose, pixels, 0.0)
    errors = np.linalg.norm(on_floor[:, :2] - objects[:, :2], axis=1)
    return Calibration(pose, rms_px, float(np.sqrt(np.mean(errors**2))), float(errors.max()), used)
