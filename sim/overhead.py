"""The simulated overhead camera: what a ceiling camera sees of the lab's floor and its robots.

`OverheadRenderer` draws a grey floor with the world's floor markers (``[[floor_marker]]``)
and, per frame, every robot at its true pose: a dark round body and, on top of it, the robot's
ArUco marker (``[extloc]`` of its config) with a white border of one cell, its top edge towards
the robot's front. Robots are drawn lowest first, so a higher one hides a lower one. Then
lighting changes and sensor noise, from a seeded generator, like the robot's camera
(`icefloe.sim.camera`). The lens is a pinhole (no distortion).

Markers are drawn anti-aliased, at `SUPERSAMPLE` times the resolution and averaged down, so
their corners land where the geometry says: the localizer's accuracy is then its own, not
the renderer's.

A world with a road (``track = ...``, `icefloe.track`) is drawn in colour: its tiles and stop
lines lie on the floor as the robot's camera sees them (`icefloe.sim.floor`), warped by the floor
plane's homography; its signs stand too low to matter from the ceiling and are not drawn.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from icefloe.vision.geometry import Intrinsics
from icefloe.vision.overhead import CameraPose, flat_square_corners, project
from icefloe.worldmap import WorldMap

from .floor import shared_floor_texture

SUPERSAMPLE = 4
BODY_RADIUS = 0.14
"""Radius of a robot's body seen from above, m (a PenguinPi is about 25 cm across, wider than its marker)."""


@dataclass(frozen=True)
class RobotView:
    """One robot to draw: its top marker and its true pose."""

    marker_id: int
    marker_size: float
    """Side of the black square, m."""
    marker_height: float
    """Height of the marker above the floor, m."""
    x: float
    y: float
    theta: float


class OverheadRenderer:
    """Frames of the overhead camera; not thread-safe (one renderer per thread)."""

    def __init__(self, world: WorldMap, intrinsics: Intrinsics, pose: CameraPose, dictionary: str, *,
                 seed: int = 1, noise: float = 2.0, lighting: float = 0.1) -> None:
        if intrinsics.dist_coeffs.any():
            raise ValueError("the simulated overhead camera has a pinhole lens (no distortion)")
        self.world, self.intrinsics, self.pose = world, intrinsics, pose
        self.width, self.height = intrinsics.width, intrinsics.height
        self._dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
        self._cells = self._dictionary.markerSize + 2
        self._count = self._dictionary.bytesList.shape[0]
        self._textures: dict[tuple[int, int], np.ndarray] = {}
        self.noise, self.lighting = noise, lighting
        self._rng = np.random.default_rng(seed)
        self._colour = world.track is not None
        shape = (self.height, self.width, 3) if self._colour else (self.height, self.width)
        self._noise_bank = [self._rng.normal(0.0, noise, shape).astype(np.int16)
                            for _ in range(4)] if noise > 0 else []
        self._floor = self._make_floor()

    def _make_floor(self) -> np.ndarray:
        """The floor with its markers: drawn once, copied for each frame."""
        rows = np.arange(self.height, dtype=np.float32)[:, None]
        cols = np.arange(self.width, dtype=np.float32)[None, :]
        floor = (110 + 20 * rows / self.height + 10 * cols / self.width).astype(np.uint8)
        if self.world.track is not None:
            floor = self._draw_road(cv2.cvtColor(floor, cv2.COLOR_GRAY2BGR))
        for marker in self.world.floor_markers:
            self.draw_marker(floor, marker.id, marker.size, flat_square_corners(
                marker.x, marker.y, 0.0, marker.yaw, marker.size / 2 * self._cells / (self._cells - 2)))
        return floor

    def _draw_road(self, floor: np.ndarray) -> np.ndarray:
        """The track's tiles on ``floor`` (BGR): the floor texture through the homography
        texture pixel → world (x, y, 0) → image (the lens is a pinhole)."""
        assert self.world.track is not None
        texture, world_from_texture = shared_floor_texture(self.world.track)
        r, t = self.pose.rotation, np.asarray(self.pose.translation, dtype=float).reshape(3)
        h = self.intrinsics.camera_matrix @ np.column_stack([r[:, 0], r[:, 1], t]) @ world_from_texture
        warped = cv2.warpPerspective(texture, h, (self.width, self.height), flags=cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0, 0))
        np.copyto(floor, warped[..., :3], where=warped[..., 3:] > 127)
        return floor

    def _texture(self, marker_id: int, cell_px: int) -> np.ndarray:
        key = (marker_id, cell_px)
        tex = self._textures.get(key)
        if tex is None:
            side = (self._cells - 2) * cell_px
            inner = cv2.aruco.generateImageMarker(self._dictionary, marker_id, side, borderBits=1)
            tex = self._textures[key] = cv2.copyMakeBorder(inner, cell_px, cell_px, cell_px, cell_px,
                                                           cv2.BORDER_CONSTANT, value=255)
        return tex

    def draw_marker(self, image: np.ndarray, marker_id: int, size: float, quiet: np.ndarray) -> None:
        """Warp marker ``marker_id`` with its white border onto the world quad ``quiet`` (4x3, the
        border's outer corners), anti-aliased."""
        if not 0 <= marker_id < self._count:
            raise ValueError(f"marker id {marker_id} is not in the overhead camera's dictionary")
        if (self.pose.to_camera(quiet)[:, 2] <= 0.01).any():
            return
        quad = project(self.intrinsics, self.pose, quiet)
        x0, y0 = np.floor(quad.min(axis=0)).astype(int)
        x1, y1 = np.ceil(quad.max(axis=0)).astype(int) + 1
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, self.width), min(y1, self.height)
        if x1 <= x0 or y1 <= y0:
            return
        f = SUPERSAMPLE
        big = cv2.resize(image[y0:y1, x0:x1], None, fx=f, fy=f, interpolation=cv2.INTER_NEAREST)
        big_quad = (quad - [x0, y0] + 0.5) * f - 0.5
        side = max(np.linalg.norm(big_quad[1] - big_quad[0]), np.linalg.norm(big_quad[3] - big_quad[0]))
        cell_px = 2
        while cell_px < 64 and cell_px < side / self._cells:
            cell_px *= 2
        tex = self._texture(marker_id, cell_px)
        if image.ndim == 3:
            tex = cv2.cvtColor(tex, cv2.COLOR_GRAY2BGR)
        th, tw = tex.shape[:2]
        src = np.float32([[-0.5, -0.5], [tw - 0.5, -0.5], [tw - 0.5, th - 0.5], [-0.5, th - 0.5]])
        h = cv2.getPerspectiveTransform(src, np.float32(big_quad))
        cv2.warpPerspective(tex, h, (big.shape[1], big.shape[0]), dst=big, flags=cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_TRANSPARENT)
        image[y0:y1, x0:x1] = cv2.resize(big, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)

    def _draw_body(self, image: np.ndarray, robot: RobotView) -> None:
        angles = np.linspace(0, 2 * math.pi, 32, endpoint=False)
        rim = np.column_stack([robot.x + BODY_RADIUS * np.cos(angles), robot.y + BODY_RADIUS * np.sin(angles),
                               np.full(len(angles), max(robot.marker_height - 0.005, 0.0))])
        if (self.pose.to_camera(rim)[:, 2] <= 0.01).any():
            return
        cv2.fillPoly(image, [np.round(project(self.intrinsics, self.pose, rim) * 16).astype(np.int32)], (45, 45, 45),
                     lineType=cv2.LINE_AA, shift=4)

    def render(self, robots: Sequence[RobotView]) -> np.ndarray:
        """One BGR frame (height x width x 3, uint8) with these robots at their poses."""
        image = self._floor.copy()
        for robot in sorted(robots, key=lambda r: r.marker_height):
            self._draw_body(image, robot)
            quiet = flat_square_corners(robot.x, robot.y, robot.marker_height, robot.theta,
                                        robot.marker_size / 2 * self._cells / (self._cells - 2))
            self.draw_marker(image, robot.marker_id, robot.marker_size, quiet)
        return self._finish(image)

    def _finish(self, image: np.ndarray) -> np.ndarray:
        gain = 1.0 + self.lighting * self._rng.uniform(-1.0, 1.0)
        gray = cv2.convertScaleAbs(image, alpha=gain)
        if self._noise_bank:
            gray = cv2.add(gray, self._noise_bank[self._rng.integers(len(self._noise_bank))], dtype=cv2.CV_8U)
        return gray if self._colour else cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
