"""The old PenguinPi localiser's square: its frame, its units and its picture. No bus here.

The old localiser (qcr/PenguinPi-robot, ``software/python/localiser/localiser.py``) looked down on
a 2 m square, rectified it to 500 x 500 pixels (4 mm each) and answered in that square's frame:

* ``x``, ``y``: the robot's pixel divided by 250, so metres from the square's corner, along its
  sides (``x = (center_box.cx / 500) * 2``);
* ``theta``: ``np.rad2deg(np.arctan2(...))`` of the same pixels, so **degrees** counter-clockwise
  from the square's +x axis, in (-180, 180];
* ``0, 0, 0`` whenever it saw no robot;
* ``/camera/get``: that rectified view, grey, flipped so that the square's +y points up the
  picture, as a PNG, with an arrow along the robot's heading.

`OldSquare` says where that square lies in the lab's world (``overhead.old_square_x``, ``_y``,
``_yaw``) and turns world poses into the old API's numbers; `picture_maps` and `picture` make its
picture from an overhead frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from icefloe.angles import wrap_angle
from icefloe.config import Overhead
from icefloe.vision.geometry import Intrinsics
from icefloe.vision.overhead import CameraPose, project

SIDE_M = 2.0
"""The old square's side, m."""
SIDE_PX = 500
"""The old picture's side, pixels (the old localiser's ``warpPerspective(..., (500, 500))``)."""
PX_PER_M = SIDE_PX / SIDE_M
ARROW_PX = 35
"""Length of the heading arrow in the picture, pixels (the old localiser's ``l = 35``)."""


@dataclass(frozen=True)
class OldSquare:
    """Where the old square lies in the world: its corner (old 0, 0), m, and the direction of its
    +x axis, rad CCW from the world's +x."""

    x: float = -0.5
    y: float = -0.5
    yaw: float = 0.0

    @classmethod
    def from_config(cls, overhead: Overhead) -> OldSquare:
        return cls(overhead.old_square_x, overhead.old_square_y, overhead.old_square_yaw)

    def pose(self, x: float, y: float, theta: float) -> tuple[float, float, float]:
        """A world pose (m, m, rad) as the old API gives it: m, m from the corner along the square's
        sides, and degrees CCW from its +x axis in (-180, 180]."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        dx, dy = x - self.x, y - self.y
        return c * dx + s * dy, -s * dx + c * dy, math.degrees(wrap_angle(theta - self.yaw))

    def world(self, old_xy: np.ndarray) -> np.ndarray:
        """Points of the old frame (n, 2), m → the world's floor (n, 3), z = 0."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        pts = np.asarray(old_xy, dtype=float).reshape(-1, 2)
        wx = self.x + c * pts[:, 0] - s * pts[:, 1]
        wy = self.y + s * pts[:, 0] + c * pts[:, 1]
        return np.column_stack([wx, wy, np.zeros(len(pts))])


def to_picture(old_x: float, old_y: float) -> tuple[float, float]:
    """A point of the old frame, m → (column, row) in the old picture (pixel centres at integers;
    the square's +y points up the picture, as the old localiser flipped it)."""
    return old_x * PX_PER_M - 0.5, SIDE_PX - old_y * PX_PER_M - 0.5


def seen_on_floor(camera: CameraPose, x: float, y: float, height: float) -> tuple[float, float]:
    """Where a point ``height`` m above the floor at world (x, y) appears in a picture of the floor:
    where the ray from the lens through it meets the floor (outward of it, the more so the further
    it is from below the lens). A robot's arrow is drawn there, on its top marker."""
    lens = camera.lens
    scale = lens[2] / (lens[2] - height)
    return float(lens[0] + (x - lens[0]) * scale), float(lens[1] + (y - lens[1]) * scale)


MAP_STEP_PX = 4
"""The old picture's pixels are projected into the frame every this many, and the maps interpolated
between them: 16 000 points instead of 250 000 (40 ms in all, where cv2.projectPoints of every pixel
took 0.2-1.1 s on this loaded machine), within 0.002 px of projecting each one, with a wide lens's
distortion too (the floor's image varies smoothly; tests/test_extloc_oldapi.py)."""


def picture_maps(square: OldSquare, intrinsics: Intrinsics, camera: CameraPose) -> tuple[np.ndarray, np.ndarray]:
    """For `cv2.remap`: the overhead frame's pixel that each pixel of the old picture sees on the
    floor (the lens's distortion included)."""
    ticks = np.arange(0, SIDE_PX + MAP_STEP_PX, MAP_STEP_PX, dtype=float)  # 0, 4, ..., 500
    cols, rows = np.meshgrid(ticks, ticks)
    old = np.column_stack([(cols.ravel() + 0.5) / PX_PER_M, (SIDE_PX - rows.ravel() - 0.5) / PX_PER_M])
    coarse = project(intrinsics, camera, square.world(old)).reshape(len(ticks), len(ticks), 2)
    at = np.arange(SIDE_PX)
    k, f = at // MAP_STEP_PX, (at % MAP_STEP_PX / MAP_STEP_PX)
    fr, fc = f[:, None, None], f[None, :, None]  # bilinear between the four samples around each pixel
    top = coarse[k][:, k] * (1 - fc) + coarse[k][:, k + 1] * fc
    bottom = coarse[k + 1][:, k] * (1 - fc) + coarse[k + 1][:, k + 1] * fc
    pixels = (top * (1 - fr) + bottom * fr).astype(np.float32)
    return pixels[..., 0], pixels[..., 1]


def picture_maps_exact(square: OldSquare, intrinsics: Intrinsics, camera: CameraPose) -> tuple[np.ndarray, np.ndarray]:
    """`picture_maps`, each pixel projected (slow: for tests)."""
    cols, rows = np.meshgrid(np.arange(SIDE_PX, dtype=float), np.arange(SIDE_PX, dtype=float))
    old = np.column_stack([(cols.ravel() + 0.5) / PX_PER_M, (SIDE_PX - rows.ravel() - 0.5) / PX_PER_M])
    pixels = project(intrinsics, camera, square.world(old)).astype(np.float32)
    return pixels[:, 0].reshape(SIDE_PX, SIDE_PX), pixels[:, 1].reshape(SIDE_PX, SIDE_PX)


def picture(frame: np.ndarray, maps: tuple[np.ndarray, np.ndarray],
            robots: Sequence[tuple[str, tuple[float, float, float]]]) -> np.ndarray:
    """The old picture: the square's floor seen from above in grey (black outside the frame), and
    for each robot (label, its old pose) an arrow along its heading from its centre, with its label."""
    grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if frame.ndim == 3 else frame
    image = cv2.remap(grey, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    for label, (x, y, theta_deg) in robots:
        col, row = to_picture(x, y)
        heading = math.radians(theta_deg)
        tip = (round(col + ARROW_PX * math.cos(heading)), round(row - ARROW_PX * math.sin(heading)))
        start = (round(col), round(row))
        for shade, width in ((0, 4), (255, 2)):  # white on a black edge: seen on any floor
            cv2.arrowedLine(image, start, tip, shade, width)
            cv2.putText(image, label, (start[0] + 8, start[1] + 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, shade, width)
    return image
