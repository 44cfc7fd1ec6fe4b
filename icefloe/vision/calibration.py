"""Camera calibration from views of a chessboard or a ChArUco board (``icefloe calibrate``).

OpenCV does the work, as in its own ``samples/python/calibrate.py``:

* a chessboard: ``cv2.findChessboardCorners`` then ``cv2.cornerSubPix`` (the whole board
  must be in the picture);
* a ChArUco board: ``cv2.aruco.CharucoDetector`` (any 6 or more of its corners will do,
  so the board may be cut by the image edge: good for the picture's corners);
* then ``cv2.calibrateCamera`` over every view: the camera matrix, the distortion
  k1, k2, p1, p2 (k3 is held at 0: a robot's few views cannot pin it down), and the
  RMS reprojection error in pixels.

`Board` describes the printed board; `find` looks for it in one image; `calibrate`
solves for the intrinsics; `geometry.save_calibration` writes what the camera service reads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from .geometry import Intrinsics

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

    @property
    def inner(self) -> tuple[int, int]:
        """Inner corners across and down (where four squares meet)."""
        return self.columns - 1, self.rows - 1

    def describe(self) -> str:
        cols, rows = self.inner
        what = "chessboard" if self.kind == "chessboard" else f"ChArUco board ({self.dictionary}, " \
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
        return cv2.aruco.CharucoBoard((self.columns, self.rows), self.square, self.marker, dictionary)


@dataclass(frozen=True)
class View:
    """The board found in one image: its corners in the image and on the board."""

    image_points: np.ndarray
    """n x 1 x 2, float32, pixels."""
    object_points: np.ndarray
    """n x 3, float32, m (z = 0: the board's plane)."""

    @property
    def count(self) -> int:
        return len(self.object_points)


class Finder:
    """Finds one board in images (keeps OpenCV's detector between images)."""

    def __init__(self, board: Board) -> None:
        self.board = board
        self._charuco = cv2.aruco.CharucoDetector(board.charuco()) if board.kind == "charuco" else None

    def find(self, image: np.ndarray) -> View | None:
        """The board in ``image`` (BGR or grey), or None where it is not (wholly) seen."""
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
        if self._charuco is not None:
            corners, ids, _, _ = self._charuco.detectBoard(gray)
            if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
                return None
            obj, img = self.board.charuco().matchImagePoints(corners, ids)
            return View(img.astype(np.float32).reshape(-1, 1, 2), obj.astype(np.float32).reshape(-1, 3))
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
        found, corners = cv2.findChessboardCorners(gray, self.board.inner, flags=flags)
        if not found:
            return None
        corners = cv2.cornerSubPix(gray, corners, SUBPIX_WINDOW, (-1, -1), SUBPIX_CRITERIA)
        return View(corners.astype(np.float32).reshape(-1, 1, 2), self.board.corners())


@dataclass(frozen=True)
class Calibration:
    intrinsics: Intrinsics
    rms: float
    """RMS reprojection error over every corner of every view, px."""
    view_errors: list[float]
    """RMS reprojection error of each view, px (a bad view stands out)."""


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
    return Calibration(Intrinsics(k, dist.reshape(-1), width, height), float(rms), errors)


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
