"""The simulated camera: renders the world's ArUco markers as the robot's camera would see them.

Given the robot's true pose, the camera's mounting and intrinsics, `CameraRenderer`
draws a grey image (walls above the horizon, floor below), warps each marker that
faces the camera into it with the right perspective, then adds lighting changes
and sensor noise (from a seeded generator, so a test can replay a run) and an
optional blur. It also returns the ground truth: which markers are fully in view,
and their range and bearing from the robot's centre, to score a detector against.

Markers are real ArUco bit patterns from ``cv2.aruco`` with a white quiet border
of one cell around the black square, as you would print them. The room is empty
and convex (markers on its walls face inward), so nothing is ever occluded.
Lens distortion is not rendered: use the nominal camera (or a calibration with
zero distortion) in simulation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from icefloe.services.camera.geometry import Intrinsics, Mount, range_bearing
from icefloe.worldmap import WorldMap

NEAR = 0.02
"""Points closer than this in front of the lens (m) are not drawn."""


@dataclass(frozen=True)
class Visible:
    """Ground truth for one marker fully inside the rendered image."""

    id: int
    range: float
    """From the robot's centre to the marker's centre, in the floor plane, m."""
    bearing: float
    """From the robot's heading, rad, CCW positive."""
    distance: float
    """From the lens to the marker's centre, m."""
    incidence: float
    """Angle between the marker's face normal and the line to the lens, rad (0 = face on)."""
    corners: np.ndarray
    """The black square's corners in the image, 4x2 pixels, OpenCV order (TL, TR, BR, BL)."""


def marker_corners(x: float, y: float, z: float, yaw: float, half: float) -> np.ndarray:
    """World corners (4x3, m) of a square of half-side ``half`` centred at (x, y, z), facing ``yaw``.

    Order as ArUco reports them, seen from the front: top-left, top-right,
    bottom-right, bottom-left.
    """
    # Someone facing the marker looks along -normal; their right hand points along `right`.
    right = np.array([-math.sin(yaw), math.cos(yaw), 0.0]) * half
    up = np.array([0.0, 0.0, half])
    c = np.array([x, y, z])
    return np.array([c - right + up, c + right + up, c + right - up, c - right - up])


class CameraRenderer:
    """Renders frames of a world for one camera; not thread-safe (one renderer per thread)."""

    def __init__(
        self,
        world: WorldMap,
        intrinsics: Intrinsics,
        mount: Mount,
        dictionary: str = "DICT_4X4_50",
        *,
        seed: int = 1,
        noise: float = 3.0,
        lighting: float = 0.15,
        blur: float = 0.0,
    ) -> None:
        """``noise``: pixel noise, standard deviation in grey levels; ``lighting``: relative
        frame-to-frame brightness change (0.15 = up to ±15 %); ``blur``: Gaussian blur sigma, px."""
        self.world, self.k, self.mount = world, intrinsics.camera_matrix, mount
        self.width, self.height = intrinsics.width, intrinsics.height
        self.noise, self.lighting, self.blur = noise, lighting, blur
        self._dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
        self._cells = self._dictionary.markerSize + 2  # bits plus the black border
        self._rng = np.random.default_rng(seed)
        ids = [m.id for m in world.markers]
        too_big = [i for i in ids if i >= self._dictionary.bytesList.shape[0]]
        if too_big:
            raise ValueError(f"world {world.name}: marker id {too_big[0]} is not in {dictionary}")
        # Per marker: the black square's corners and those of the square with its quiet border.
        self._black = np.array([marker_corners(m.x, m.y, m.z, m.yaw, m.size / 2) for m in world.markers])
        pad = (self._cells + 2) / self._cells
        self._quiet = np.array([marker_corners(m.x, m.y, m.z, m.yaw, m.size / 2 * pad)
                                for m in world.markers])
        self._normals = np.array([[math.cos(m.yaw), math.sin(m.yaw), 0.0] for m in world.markers])
        self._centres = np.array([[m.x, m.y, m.z] for m in world.markers])
        self._textures: dict[tuple[int, int], np.ndarray] = {}
        self._background = self._make_background()
        # A bank of noise images drawn once: drawing 300 k normals per frame would cost more
        # than the whole rest of the render.
        self._noise_bank = [
            self._rng.normal(0.0, noise, (self.height, self.width)).astype(np.int16) for _ in range(8)
        ]

    # ------------------------------------------------------------------ drawing

    def _make_background(self) -> np.ndarray:
        """Plain walls above the horizon, a darker floor below it, with gentle gradients."""
        horizon = self.k[1, 2]
        rows = np.arange(self.height, dtype=np.float32)[:, None]
        wall = 175 + 20 * (rows / self.height)
        floor = 95 + 40 * ((rows - horizon) / max(self.height - horizon, 1))
        column = np.where(rows < horizon, wall, floor)
        return np.repeat(column, self.width, axis=1).clip(0, 255).astype(np.uint8)

    def _texture(self, marker_id: int, cell_px: int) -> np.ndarray:
        """The marker with a one-cell white quiet border, ``cell_px`` pixels per cell (cached)."""
        key = (marker_id, cell_px)
        tex = self._textures.get(key)
        if tex is None:
            inner = cv2.aruco.generateImageMarker(self._dictionary, marker_id, self._cells * cell_px, borderBits=1)
            tex = cv2.copyMakeBorder(inner, cell_px, cell_px, cell_px, cell_px, cv2.BORDER_CONSTANT, value=255)
            self._textures[key] = tex
        return tex

    def _project(self, points_camera: np.ndarray) -> np.ndarray:
        """Camera-frame points (..., 3), m → pixels (..., 2)."""
        z = points_camera[..., 2:3]
        uv = points_camera[..., :2] / z
        return uv * [self.k[0, 0], self.k[1, 1]] + [self.k[0, 2], self.k[1, 2]]

    def _draw(self, image: np.ndarray, marker_id: int, quad: np.ndarray, black: np.ndarray) -> None:
        """Warp one marker's texture onto ``quad`` (4x2 px), touching only its bounding box."""
        x0, y0 = np.floor(quad.min(axis=0)).astype(int)
        x1, y1 = np.ceil(quad.max(axis=0)).astype(int) + 1
        x0, y0 = max(x0, 0), max(y0, 0)
        x1, y1 = min(x1, self.width), min(y1, self.height)
        if x1 <= x0 or y1 <= y0:
            return
        # Pick the texture resolution nearest above the on-screen cell size (a mip-map):
        # warping a much larger texture down would alias the cell edges.
        side_px = max(np.linalg.norm(black[1] - black[0]), np.linalg.norm(black[3] - black[0]))
        cell_px = 2
        while cell_px < 64 and cell_px < side_px / self._cells:
            cell_px *= 2
        tex = self._texture(marker_id, cell_px)
        n = tex.shape[0]
        # Pixel centres sit at integer coordinates, so the texture's outer edge is at -0.5 and n-0.5.
        src = np.float32([[-0.5, -0.5], [n - 0.5, -0.5], [n - 0.5, n - 0.5], [-0.5, n - 0.5]])
        dst = np.float32(quad - [x0, y0])
        h = cv2.getPerspectiveTransform(src, dst)
        roi = np.ascontiguousarray(image[y0:y1, x0:x1])
        cv2.warpPerspective(tex, h, (x1 - x0, y1 - y0), dst=roi, flags=cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_TRANSPARENT)
        image[y0:y1, x0:x1] = roi

    # ------------------------------------------------------------------ the frame

    def render(self, x: float, y: float, theta: float) -> tuple[np.ndarray, list[Visible]]:
        """One BGR frame (height x width x 3, uint8) seen from the robot at pose (x m, y m, theta rad),
        and the markers fully inside it."""
        c, s = math.cos(theta), math.sin(theta)
        world_from_robot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        robot_origin = np.array([x, y, 0.0])
        world_from_camera = world_from_robot @ self.mount.robot_from_camera()
        lens = robot_origin + world_from_robot @ [self.mount.x, self.mount.y, self.mount.z]

        def to_camera(points_world: np.ndarray) -> np.ndarray:
            return (points_world - lens) @ world_from_camera  # row vectors: R^T (p - lens)

        quiet_c, black_c = to_camera(self._quiet), to_camera(self._black)
        to_lens = lens - self._centres
        distance = np.linalg.norm(to_lens, axis=1)
        facing = np.einsum("ij,ij->i", self._normals, to_lens) > 0
        in_front = (quiet_c[..., 2] > NEAR).all(axis=1)

        image = self._background.copy()
        visible: list[Visible] = []
        for i in np.flatnonzero(facing & in_front):
            marker = self.world.markers[i]
            quad, black = self._project(quiet_c[i]), self._project(black_c[i])
            self._draw(image, marker.id, quad, black)
            inside = ((black >= 0) & (black <= [self.width - 1, self.height - 1])).all()
            if inside:
                rng, bearing = range_bearing(world_from_robot.T @ (self._centres[i] - robot_origin))
                cos_inc = float(self._normals[i] @ to_lens[i]) / distance[i]
                visible.append(Visible(marker.id, rng, bearing, float(distance[i]),
                                       math.acos(min(1.0, cos_inc)), black))
        return self._finish(image), visible

    def _finish(self, image: np.ndarray) -> np.ndarray:
        """Lighting change, sensor noise and blur, then grey → BGR like a colour camera's output."""
        gain = 1.0 + self.lighting * self._rng.uniform(-1.0, 1.0)
        if self.blur > 0:
            image = cv2.GaussianBlur(image, (0, 0), self.blur)
        gray = cv2.convertScaleAbs(image, alpha=gain)  # saturates at 0 and 255
        if self.noise > 0:
            noise = self._noise_bank[self._rng.integers(len(self._noise_bank))]
            gray = cv2.add(gray, noise, dtype=cv2.CV_8U)
        return cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
