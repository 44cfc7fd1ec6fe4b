"""Camera calibration from views of a chessboard or a ChArUco board (``icefloe calibrate``).

OpenCV does the work, as in its own ``samples/python/calibrate.py``:

* a chessboard: ``cv2.findChessboardCorners`` then ``cv2.cornerSubPix`` (the whole board
  must be in the picture);
* a ChArUco board: ``cv2.aruco.CharucoDetector`` (any 6 or more of its corners will do,
  so the board may be cut by the image edge: good for the picture's corners);
* then ``cv2.calibrateCamera`` over every view: the camera matrix, the distortion
  k1, k2, p1, p2 (k3 is held at 0: a robot's few views cannot pin it down), and the
  RMS reprojection error in pixels.

A ChArUco board's markers measure the robot's own marker detector too (`measure_inset`): the
camera service's detector (`aruco.robot_detector`) finds them, and the board's pose puts their
true corners a fraction of a pixel outside where it found them; that inset, the less the larger
the marker, makes every range it measures long until the camera service undoes it.

`Board` describes the printed board; `find` looks for it in one image; `calibrate`
solves for the intrinsics; `geometry.save_calibration` writes what the camera service reads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from .aruco import robot_detector
from .geometry import Intrinsics, MarkerInset

MIN_CHARUCO_CORNERS = 6
"""Fewer ChArUco corners than this in a view tell too little to use it."""
SUBPIX_WINDOW = (5, 5)
"""Half-size of `cv2.cornerSubPix`'s search window, px (chessboard squares are >= 12 px here)."""
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 0.001)


@dataclass(frozen=True)
class Board:
    """A printed calibration board: ``columns`` x ``rows`` squares of ``square`` m (and, on a
    ChArUco board, ArUco markers of ``marker`` m from ``dictionary``)."""

    columns: int
    rows: int
    square: float
    kind: Literal["chessboard", "charuco"] = "chessboard"
    marker: float = 0.0
    dictionary: str = "DICT_5X5_100"
    first_id: int = 0
    """ChArUco: the id of the first marker (the others follow)."""

    def __post_init__(self) -> None:
        if self.columns < 3 or self.rows < 3:
            raise ValueError(f"board: at least 3x3 squares, got {self.columns}x{self.rows}")
        if not (math.isfinite(self.square) and self.square > 0):
            raise ValueError(f"square: must be > 0 m, got {self.square}")
        if self.kind == "charuco":
            if not 0 < self.marker < self.square:
                raise ValueError(f"marker: must be > 0 and smaller than the square ({self.square} m), "
                                 f"got {self.marker}")
            if not hasattr(cv2.aruco, self.dictionary):
                raise ValueError(f"dictionary: {self.dictionary!r} is not an OpenCV ArUco dictionary")
            size = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary)).bytesList.shape[0]
            last = self.first_id + self.columns * self.rows // 2 - 1
            if self.first_id < 0 or last >= size:
                raise ValueError(f"first id: the board's markers {self.first_id}..{last} are not all in "
                                 f"{self.dictionary} (ids 0..{size - 1})")

    @property
    def inner(self) -> tuple[int, int]:
        """Inner corners across and down (where four squares meet)."""
        return self.columns - 1, self.rows - 1

    def describe(self) -> str:
        cols, rows = self.inner
        ids = f" from id {self.first_id}" if self.first_id else ""
        what = "chessboard" if self.kind == "chessboard" else f"ChArUco board ({self.dictionary}{ids}, " \
            f"{self.marker * 1000:.1f} mm markers)"
        return f"a {what} of {self.columns}x{self.rows} squares ({cols}x{rows} inner corners), " \
               f"{self.square * 1000:.1f} mm squares"

    def corners(self) -> np.ndarray:
        """The inner corners on the board (n x 3, m, z = 0), row by row, in the order `find` reports them."""
        cols, rows = self.inner
        grid = np.zeros((cols * rows, 3), np.float32)
        grid[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * self.square
        return grid

    def charuco(self) -> cv2.aruco.CharucoBoard:
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        ids = np.arange(self.first_id, self.first_id + self.columns * self.rows // 2, dtype=np.int32)
        return cv2.aruco.CharucoBoard((self.columns, self.rows), self.square, self.marker, dictionary, ids)


@dataclass(frozen=True)
class MarkerSighting:
    """One of a ChArUco board's markers as the robot camera's detector finds it."""

    detected: np.ndarray
    """Its black square's corners in the image, 4 x 2 px (the detector's order)."""
    board: np.ndarray
    """The same corners on the board, 4 x 3 m."""


@dataclass(frozen=True)
class View:
    """The board found in one image: its corners in the image and on the board."""

    image_points: np.ndarray
    """n x 1 x 2, float32, pixels."""
    object_points: np.ndarray
    """n x 3, float32, m (z = 0: the board's plane)."""
    markers: tuple[MarkerSighting, ...] = ()
    """A ChArUco board's markers, as the robot camera's marker detector found them."""

    @property
    def count(self) -> int:
        return len(self.object_points)


class Finder:
    """Finds one board in images (keeps OpenCV's detector between images)."""

    def __init__(self, board: Board) -> None:
        self.board = board
        self._charuco = cv2.aruco.CharucoDetector(board.charuco()) if board.kind == "charuco" else None
        if self._charuco is not None:
            printed = board.charuco()
            self._marker_corners = {int(i): np.asarray(c, float).reshape(4, 3)
                                    for i, c in zip(printed.getIds().ravel(), printed.getObjPoints(), strict=True)}
            self._markers = robot_detector(board.dictionary)

    def find(self, image: np.ndarray) -> View | None:
        """The board in ``image`` (BGR or grey), or None where it is not (wholly) seen."""
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
        if self._charuco is not None:
            corners, ids, _, _ = self._charuco.detectBoard(gray)
            if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
                return None
            obj, img = self.board.charuco().matchImagePoints(corners, ids)
            return View(img.astype(np.float32).reshape(-1, 1, 2), obj.astype(np.float32).reshape(-1, 3),
                        self._sightings(gray))
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
        found, corners = cv2.findChessboardCorners(gray, self.board.inner, flags=flags)
        if not found:
            return None
        corners = cv2.cornerSubPix(gray, corners, SUBPIX_WINDOW, (-1, -1), SUBPIX_CRITERIA)
        return View(corners.astype(np.float32).reshape(-1, 1, 2), self.board.corners())


    def _sightings(self, gray: np.ndarray) -> tuple[MarkerSighting, ...]:
        corners, ids, _ = self._markers.detectMarkers(gray)
        if ids is None:
            return ()
        return tuple(MarkerSighting(np.asarray(c, float).reshape(4, 2), self._marker_corners[int(i)])
                     for c, i in zip(corners, ids.ravel(), strict=True) if int(i) in self._marker_corners)


@dataclass(frozen=True)
class Calibration:
    intrinsics: Intrinsics
    rms: float
    """RMS reprojection error over every corner of every view, px."""
    view_errors: list[float]
    """RMS reprojection error of each view, px (a bad view stands out)."""
    poses: list[tuple[np.ndarray, np.ndarray]]
    """Each view's board pose in the camera frame (rvec, tvec), as OpenCV solved it."""


def calibrate(views: list[View], width: int, height: int) -> Calibration:
    """The intrinsics that best explain ``views`` (at least 3; 10 or more from many angles is good)."""
    if len(views) < 3:
        raise ValueError(f"calibration needs at least 3 views of the board, got {len(views)}")
    objects = [v.object_points for v in views]
    images = [v.image_points for v in views]
    rms, k, dist, rvecs, tvecs = cv2.calibrateCamera(objects, images, (width, height), None, None,
                                                     flags=cv2.CALIB_FIX_K3)
    errors = []
    for view, rvec, tvec in zip(views, rvecs, tvecs, strict=True):
        projected, _ = cv2.projectPoints(view.object_points, rvec, tvec, k, dist)
        miss = projected.reshape(-1, 2) - view.image_points.reshape(-1, 2)
        errors.append(float(np.sqrt(np.mean(np.sum(miss**2, axis=1)))))
    return Calibration(Intrinsics(k, dist.reshape(-1), width, height), float(rms), errors,
                       [(np.asarray(r), np.asarray(t)) for r, t in zip(rvecs, tvecs, strict=True)])


def with_intrinsics(views: list[View], intrinsics: Intrinsics) -> Calibration:
    """The board's pose in each view for intrinsics already known (``icefloe calibrate
    --keep-intrinsics``), and how well they explain the views."""
    if not views:
        raise ValueError("no views of the board")
    k, dist = intrinsics.camera_matrix, intrinsics.dist_coeffs
    poses, errors, misses = [], [], []
    for view in views:
        ok, rvec, tvec = cv2.solvePnP(view.object_points, view.image_points, k, dist)
        if not ok:
            raise ValueError("the board's pose in a view could not be solved")
        projected, _ = cv2.projectPoints(view.object_points, rvec, tvec, k, dist)
        miss = np.sum((projected.reshape(-1, 2) - view.image_points.reshape(-1, 2)) ** 2, axis=1)
        misses.append(miss)
        errors.append(float(np.sqrt(np.mean(miss))))
        poses.append((rvec, tvec))
    return Calibration(intrinsics, float(np.sqrt(np.mean(np.concatenate(misses)))), errors, poses)


@dataclass(frozen=True)
class InsetFit:
    """What `measure_inset` found."""

    inset: MarkerInset
    markers: int
    """Sightings of markers it used."""
    sides: tuple[float, float]
    """The smallest and largest of their sides in the picture, px."""
    residual: float
    """The RMS of the per-sighting insets about the fit, px."""


MIN_INSET_SIGHTINGS = 20
"""Fewer sightings of a ChArUco board's markers than this measure no inset."""


def measure_inset(views: list[View], result: Calibration) -> InsetFit | None:
    """How far inside their black squares the robot camera's detector puts the corners of the board's
    markers: against where the board's pose (``result``) and the lens put them, each edge's offset
    along its normal, averaged per sighting, fitted as ``px + px2 / side`` (`MarkerInset`); a constant
    when the sides span too little to tell the two apart. None without enough sightings (a chessboard)."""
    k, dist = result.intrinsics.camera_matrix, result.intrinsics.dist_coeffs
    sides, insets = [], []
    for view, (rvec, tvec) in zip(views, result.poses, strict=True):
        for sighting in view.markers:
            true = cv2.projectPoints(sighting.board, rvec, tvec, k, dist)[0].reshape(4, 2)
            edges = np.roll(true, -1, axis=0) - true
            lengths = np.linalg.norm(edges, axis=1)
            normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1) / lengths[:, None]
            inward = ((true.mean(axis=0) - (true + edges / 2)) * normals).sum(axis=1) > 0
            normals[~inward] *= -1                                  # each one inward
            miss = sighting.detected - true
            # corner i lies on edges i - 1 and i: how far in along each
            depth = [float(miss[i] @ normals[j]) for i in range(4) for j in (i - 1, i)]
            sides.append(float(lengths.mean()))
            insets.append(float(np.mean(depth)))
    if len(insets) < MIN_INSET_SIGHTINGS:
        return None
    side, inset = np.array(sides), np.array(insets)
    if side.max() / side.min() >= 1.5:
        a = np.stack([np.ones_like(side), 1.0 / side], axis=1)
        (px, px2), *_ = np.linalg.lstsq(a, inset, rcond=None)
        px2 = max(px2, 0.0)  # an inset that grows with the marker is noise, not the detector
        px = float(np.mean(inset - px2 / side)) if px2 == 0.0 else px
    else:
        px, px2 = float(inset.mean()), 0.0
    fit = MarkerInset(float(px), float(px2))
    residual = float(np.sqrt(np.mean((inset - np.array([fit.at(s) for s in side])) ** 2)))
    return InsetFit(fit, len(inset), (float(side.min()), float(side.max())), residual)


def region_counts(views: list[View], width: int, height: int, grid: int = 3) -> np.ndarray:
    """How many views put a corner in each of ``grid`` x ``grid`` parts of the image (rows x columns):
    a calibration needs corners all over the picture, its corners most of all."""
    counts = np.zeros((grid, grid), int)
    for view in views:
        points = view.image_points.reshape(-1, 2)
        cells = {(min(int(y * grid / height), grid - 1), min(int(x * grid / width), grid - 1)) for x, y in points}
        for cell in cells:
            counts[cell] += 1
    return counts


def view_distance(a: View, b: View) -> float:
    """How different two views of the board are: mean distance between corners both show, px
    (inf when they share none). A chessboard's corners may come in either order (it looks the
    same turned half round): the nearer of the two is taken."""
    def mean_shift(b_points: np.ndarray) -> float:
        pa = {tuple(p): q for p, q in zip(a.object_points.round(6), a.image_points.reshape(-1, 2), strict=True)}
        shared = [np.linalg.norm(pa[tuple(p)] - q) for p, q in zip(b.object_points.round(6), b_points, strict=True)
                  if tuple(p) in pa]
        return float(np.mean(shared)) if shared else math.inf

    points = b.image_points.reshape(-1, 2)
    if a.count == b.count and np.array_equal(a.object_points, b.object_points):
        return min(mean_shift(points), mean_shift(points[::-1]))
    return mean_shift(points)


def board_yaw(view: View, intrinsics: Intrinsics) -> float | None:
    """Which way the board faces in the camera frame, about the camera's vertical (rad): it changes by
    exactly the robot's turn (one way or the other, as the board's axes go), wherever the board is.
    None if its pose cannot be solved."""
    ok, rvec, _ = cv2.solvePnP(view.object_points, view.image_points, intrinsics.camera_matrix,
                               intrinsics.dist_coeffs)
    if not ok:
        return None
    normal = cv2.Rodrigues(rvec)[0][:, 2]  # the board's z axis in the camera frame (x right, y down, z ahead)
    return math.atan2(float(normal[0]), float(normal[2]))


@dataclass(frozen=True)
class LatencyFit:
    """What `fit_latency` found."""

    latency_s: float
    """How much later the frames' stamps are than their exposure, against odometry's clock, s."""
    frames: int
    residual: float
    """RMS of the board's yaw about the fit, rad."""
    gain: float
    """How the board's yaw followed odometry's heading (±1 as it should: its sign is the board's
    axes'; a track not yet calibrated makes it a few % off)."""


LATENCY_RANGE_S = (-0.1, 0.4)
"""`fit_latency` looks for the latency in this range, s, in steps of 1 ms."""


def fit_latency(frames: list[tuple[int, float]], headings: list[tuple[int, float]]) -> LatencyFit | None:
    """The capture latency from a turn back and forth in front of a board: ``frames`` (stamp ns, the
    board's yaw `board_yaw` in that frame), ``headings`` (stamp ns, odometry's heading, unwrapped).
    The board stands still, so its yaw is a constant minus the heading at the frame's exposure, which
    is ``latency`` before its stamp: the latency is the shift that fits a line best. (The slope is free:
    a track not yet calibrated makes odometry's turn a little long or short.) None with too few frames
    or none of the heading history around them."""
    if len(frames) < 10 or len(headings) < 10:
        return None
    t = np.array([s for s, _ in headings], dtype=np.float64) * 1e-9
    theta = np.array([h for _, h in headings])
    stamps = np.array([s for s, _ in frames], dtype=np.float64) * 1e-9
    yaw = np.unwrap(np.array([y for _, y in frames]))
    low, high = LATENCY_RANGE_S
    inside = (stamps - high >= t[0]) & (stamps - low <= t[-1])  # odometry around every shift tried
    stamps, yaw = stamps[inside], yaw[inside]
    if len(stamps) < 10:
        return None
    best: tuple[float, float, float] = (math.inf, 0.0, 0.0)
    for lag in np.arange(low, high, 0.001):
        heading = np.interp(stamps - lag, t, theta)
        a = np.stack([np.ones_like(heading), heading], axis=1)
        coeffs, *_ = np.linalg.lstsq(a, yaw, rcond=None)
        rms = float(np.sqrt(np.mean((a @ coeffs - yaw) ** 2)))
        if rms < best[0]:
            best = (rms, float(lag), float(coeffs[1]))
    rms, lag, gain = best
    return LatencyFit(lag, len(stamps), rms, gain)
