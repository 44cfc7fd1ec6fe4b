"""The simulated camera: renders the world's ArUco markers as the robot's camera would see them.

Given the robot's true pose, the camera's mounting and intrinsics, `CameraRenderer`
draws a grey image (walls above the horizon, floor below), warps each marker that
faces the camera into it with the right perspective, then adds lighting changes
and sensor noise (from a seeded generator, so a test can replay a run) and an
optional blur. It also returns the ground truth: which markers are fully in view,
and their range and bearing from the robot's centre, to score a detector against.

Markers are real ArUco bit patterns from ``cv2.aruco`` with a white quiet border
of one cell around the black square, as you would print them. Calibration boards
(a world's ``[[board]]``: chessboards, or ChArUco boards from ``cv2.aruco``) are
drawn the same way, with a white margin of one square; `CameraRenderer.board_corners`
gives their inner corners' true pixels. Both are drawn anti-aliased (`SUPERSAMPLE`: each
pixel the mean of the light on it, as on a camera's sensor), so their edges are where the lens
puts them whichever way they fall between pixels. Nearer markers are drawn over farther ones.
A marker block's faces (`WorldMap.faces`) are drawn as markers; the cube's body is not drawn.

The world's obstacles (``[[obstacle]]``: walls, boxes) are drawn as solid grey prisms standing
on the floor, one flat shade per face, with a depth buffer: a marker or board is drawn only where
no obstacle stands nearer the lens (a print on an obstacle's face, within `ON_SURFACE` of it,
shows), so a marker behind a box is hidden as a real camera would not see it, and one half
behind it is cut in half. A marker with any part of it hidden (its white quiet border
included: a detector needs it) is not in the ground truth's `Visible` list.

The lens is the intrinsics' own, distortion included: with distortion coefficients
the frame is drawn through an ideal pinhole onto a larger canvas, then bent with
``cv2.remap`` as the lens would bend it. The simulator's true lens is ``[sim.lens]``
(`true_intrinsics`), which the camera service does not know: that is what
``icefloe calibrate`` measures.

With a `Picture` of the realistic profile (`icefloe.sim.realism`), the light varies over the room
(each marker, board and obstacle face as bright as the light where it is, against the light where
the camera looks), and `sim.sensor` makes the camera's picture: motion blur from the turn rate
during the shutter auto exposure chose, the lens's softness, noise that grows with the gain, JPEG.
Without one (the ideal profile) the frame is finished as it always was: flicker, noise, blur.
A track's world is drawn in colour in both: with a realistic picture its floor and road are as
bright as the light where the robot stands, its signs as the light where they stand, and the
sensor's blur, noise and JPEG work on the three channels.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from icefloe.config import RobotConfig
from icefloe.vision import calibration
from icefloe.vision.geometry import Intrinsics, Mount, range_bearing
from icefloe.worldmap import Board, WorldMap, load_world

from . import realism
from .floor import shared_floor_texture, stop_sign_texture
from .sensor import LightField, Sensor

NEAR = 0.02
"""Points closer than this in front of the lens (m) are not drawn."""
SUPERSAMPLE = 4
"""Markers and calibration boards are drawn at this many times the frame's resolution, then averaged
down: each pixel the mean of the light on it, as a camera's sensor integrates it. A plain warp makes a
black square's edge a fraction of a pixel wide and puts it where pixel centres happen to fall, and the
marker detector's corners with it: at tests/test_localizer_at_rest.py's pose, 0.45 px inside the
square on one marker and 0.05 px outside on the other, which no calibration of the detector (measured
on boards drawn this way) can undo."""
SUPERSAMPLED_MARKER_PX = 768
"""A marker is supersampled less where its picture would grow wider than this, px: a marker filling the
view (0.15 m from 0.3 m, 330 px) took 10 ms at `SUPERSAMPLE` against 1.3 ms plainly drawn, and a
fraction of a pixel is nothing to a marker that large (0.1 % of its side)."""
ON_SURFACE = 0.01
"""A marker at most this far (m, along the line of sight) behind an obstacle's face is on it,
printed and stuck there: it shows. The lab's markers hang on the walls' inner faces."""
LIGHT = np.array([0.45, 0.3, 0.84])
"""Direction towards the light (from above, a little from +x +y): faces turned to it are brighter."""
FLOOR_FAR = 30.0
"""The road is drawn on the floor up to this far from the lens (m, along the optical axis):
beyond, the floor's texture would be minified past anything a camera resolves."""


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
    return rectangle_corners(np.array([x, y, z]), *board_axes(yaw, 0.0)[:2], half, half)


def board_axes(yaw: float, tilt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit vectors (right, up, normal) of a flat thing facing ``yaw``, leaning back by ``tilt`` (rad)."""
    # Someone facing it looks along -normal; their right hand points along `right`.
    right = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
    facing = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    up = np.array([0.0, 0.0, 1.0]) * math.cos(tilt) - facing * math.sin(tilt)
    normal = facing * math.cos(tilt) + np.array([0.0, 0.0, 1.0]) * math.sin(tilt)
    return right, up, normal


def rectangle_corners(centre: np.ndarray, right: np.ndarray, up: np.ndarray, half_w: float,
                      half_h: float) -> np.ndarray:
    """World corners (4x3) of a rectangle: top-left, top-right, bottom-right, bottom-left from the front."""
    r, u = right * half_w, up * half_h
    return np.array([centre - r + u, centre + r + u, centre + r - u, centre - r - u])


def board_inner_corners(board: Board) -> np.ndarray:
    """World positions ((columns-1) x (rows-1), 3) of a board's inner corners, row by row from the
    top-left, as seen from the front (where square corners meet)."""
    right, up, _ = board_axes(board.yaw, board.tilt)
    i, j = np.meshgrid(np.arange(1, board.columns), np.arange(1, board.rows))
    across = (i.ravel() - board.columns / 2) * board.square
    down = (j.ravel() - board.rows / 2) * board.square
    return np.array([board.x, board.y, board.z]) + np.outer(across, right) - np.outer(down, up)


def board_texture(board: Board, cell_px: int) -> np.ndarray:
    """The printed board with a white margin of one square, ``cell_px`` pixels per square (grey, uint8)."""
    w, h = (board.columns + 2) * cell_px, (board.rows + 2) * cell_px
    if board.kind == "charuco":
        printed = calibration.Board(board.columns, board.rows, board.square, "charuco", board.marker,
                                    board.dictionary, board.first_id)
        return printed.charuco().generateImage((w, h), marginSize=cell_px)
    squares = (np.add.outer(np.arange(board.rows), np.arange(board.columns)) % 2) * 255  # black top-left
    inner = np.kron(squares, np.ones((cell_px, cell_px))).astype(np.uint8)
    return cv2.copyMakeBorder(inner, cell_px, cell_px, cell_px, cell_px, cv2.BORDER_CONSTANT, value=255)


def obstacle_faces(world: WorldMap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every obstacle as the faces of a prism on the floor: its four sides and its top.

    Returns the faces' world corners (F, 4, 3), m; their outward unit normals (F, 3); and the grey
    level each is drawn with (F,), from how much it faces `LIGHT`. (A bottom face is never seen:
    it lies on the floor.)"""
    corners, normals, greys = [], [], []
    light = LIGHT / np.linalg.norm(LIGHT)
    for obstacle in world.obstacles:
        cx, cy, hl, hw, yaw = obstacle.rectangle()
        c, s = math.cos(yaw), math.sin(yaw)
        # the footprint anticlockwise seen from above, so each edge's outward normal is its direction turned -90°
        foot = [(cx + c * u - s * v, cy + s * u + c * v) for u, v in ((hl, -hw), (hl, hw), (-hl, hw), (-hl, -hw))]
        h = obstacle.height
        for (ax, ay), (bx, by) in zip(foot, foot[1:] + foot[:1], strict=True):
            corners.append([(ax, ay, h), (bx, by, h), (bx, by, 0.0), (ax, ay, 0.0)])
            edge = math.hypot(bx - ax, by - ay)
            normals.append(((by - ay) / edge, -(bx - ax) / edge, 0.0))
        corners.append([(x, y, h) for x, y in foot])
        normals.append((0.0, 0.0, 1.0))
    normals_a = np.array(normals, dtype=float).reshape(-1, 3)
    # half-Lambert: a face turned away from the light is dimmer, never black (the room has other light)
    greys = 90 + 90 * (0.5 + 0.5 * (normals_a @ light)) if len(normals_a) else np.zeros(0)
    return np.array(corners, dtype=float).reshape(-1, 4, 3), normals_a, greys.round().astype(np.uint8)


def clip_near(polygon: np.ndarray) -> np.ndarray:
    """The part of a convex camera-frame polygon (n, 3) at least `NEAR` in front of the lens
    (Sutherland-Hodgman against one plane): a wall beside the robot runs behind the camera."""
    inside = polygon[:, 2] >= NEAR
    if inside.all():
        return polygon
    out = []
    for a, b in zip(polygon, np.roll(polygon, -1, axis=0), strict=True):
        if a[2] >= NEAR:
            out.append(a)
        if (a[2] >= NEAR) != (b[2] >= NEAR):
            out.append(a + (NEAR - a[2]) / (b[2] - a[2]) * (b - a))
    return np.array(out).reshape(-1, 3)


def true_intrinsics(config: RobotConfig) -> Intrinsics:
    """The simulated camera's true lens: ``[sim.lens]``, else its profile's (`icefloe.sim.realism`):
    the realistic lens, or in the ideal profile the lens the camera service believes (its
    calibration file, or the nominal camera of ``[camera]``). A 0 is the nominal camera's value."""
    cam, lens = config.camera, realism.lens(config)
    believed = Intrinsics.from_config(cam) if realism.NOMINAL in lens.values() else None
    nominal = Intrinsics.nominal(cam.focal_px, cam.width, cam.height)

    def key(name: str, row: int, col: int, zero: float) -> float:
        v = lens[name]
        if v == realism.NOMINAL:
            assert believed is not None
            return float(believed.camera_matrix[row, col])
        return float(v) or zero

    fx = key("fx", 0, 0, cam.focal_px)
    k = np.array([[fx, 0.0, key("cx", 0, 2, nominal.camera_matrix[0, 2])],
                  [0.0, key("fy", 1, 1, fx), key("cy", 1, 2, nominal.camera_matrix[1, 2])],
                  [0.0, 0.0, 1.0]])
    dist = np.zeros(5)
    if lens["distortion"] == realism.NOMINAL:
        assert believed is not None
        given = list(believed.dist_coeffs.ravel())
    else:
        given = list(lens["distortion"])
    dist[:min(len(given), 5)] = given[:5]
    return Intrinsics(k, dist, cam.width, cam.height)


class TextureCache:
    """Textures made at the sizes they were drawn at, the most recently used kept up to `limit` bytes:
    a robot driving round sees each marker at dozens of sizes, and every size kept forever grew the
    camera service (where the simulated camera renders) by megabytes an hour (bench/stack_memory.py)."""

    def __init__(self, limit: int = 4 << 20) -> None:
        self.limit = limit
        self._kept: OrderedDict[tuple[int, int], np.ndarray] = OrderedDict()
        self._bytes = 0

    def get(self, key: tuple[int, int]) -> np.ndarray | None:
        tex = self._kept.get(key)
        if tex is not None:
            self._kept.move_to_end(key)
        return tex

    def put(self, key: tuple[int, int], tex: np.ndarray) -> None:
        self._kept[key] = tex
        self._bytes += tex.nbytes
        while self._bytes > self.limit and len(self._kept) > 1:
            self._bytes -= self._kept.popitem(last=False)[1].nbytes


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
        picture: realism.Picture | None = None,
    ) -> None:
        """``noise``: pixel noise, standard deviation in grey levels; ``lighting``: relative
        frame-to-frame brightness change (0.15 = up to ±15 %); ``blur``: Gaussian blur sigma, px.
        ``picture``: the camera's effects (`icefloe.sim.realism`); one that is not `Picture.plain`
        replaces the three above with the light, auto exposure and sensor of `sim.sensor`."""
        self.world, self.k, self.mount = world, intrinsics.camera_matrix, mount
        self.dist = np.asarray(intrinsics.dist_coeffs, dtype=float)
        self.width, self.height = intrinsics.width, intrinsics.height
        self._canvas_k, self._canvas_size, self._lens_maps = self._lens(intrinsics)
        self.noise, self.lighting, self.blur = noise, lighting, blur
        self._dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
        self._cells = self._dictionary.markerSize + 2  # bits plus the black border
        self._rng = np.random.default_rng(seed)
        self._faces = world.faces()  # markers, and each face of each block (an id may repeat)
        ids = [m.id for m in self._faces]
        too_big = [i for i in ids if i >= self._dictionary.bytesList.shape[0]]
        if too_big:
            raise ValueError(f"world {world.name}: marker id {too_big[0]} is not in {dictionary}")
        # Per marker: the black square's corners and those of the square with its quiet border.
        self._black = np.array([marker_corners(m.x, m.y, m.z, m.yaw, m.size / 2)
                                for m in self._faces]).reshape(-1, 4, 3)
        pad = (self._cells + 2) / self._cells
        self._quiet = np.array([marker_corners(m.x, m.y, m.z, m.yaw, m.size / 2 * pad)
                                for m in self._faces]).reshape(-1, 4, 3)
        self._normals = np.array([[math.cos(m.yaw), math.sin(m.yaw), 0.0] for m in self._faces]).reshape(-1, 3)
        self._centres = np.array([[m.x, m.y, m.z] for m in self._faces]).reshape(-1, 3)
        self._textures = TextureCache()
        self._board_textures = TextureCache()
        self._board_quads = np.array([rectangle_corners(np.array([b.x, b.y, b.z]), *board_axes(b.yaw, b.tilt)[:2],
                                                        (b.columns + 2) * b.square / 2, (b.rows + 2) * b.square / 2)
                                      for b in world.boards]).reshape(-1, 4, 3)
        self._board_normals = np.array([board_axes(b.yaw, b.tilt)[2] for b in world.boards]).reshape(-1, 3)
        self._board_centres = np.array([[b.x, b.y, b.z] for b in world.boards]).reshape(-1, 3)
        self._obstacles, self._obstacle_normals, self._obstacle_greys = obstacle_faces(world)
        self._obstacle_centres = self._obstacles.mean(axis=1)
        # A world with a road is drawn in colour (its tiles, its red signs); one without, in grey as always.
        self._track = world.track
        self._colour = self._track is not None
        self._background = self._make_background()
        if self._track is not None:
            self._floor, self._world_from_floor = shared_floor_texture(self._track, seed)
            self._background = cv2.cvtColor(self._background, cv2.COLOR_GRAY2BGR)
        signs = self._track.signs if self._track is not None else ()
        sign_axes = [board_axes(sign.yaw, 0.0) for sign in signs]
        # a sign's face stands on the floor: its centre half its size up
        self._sign_quads = np.array([rectangle_corners(np.array([sign.x, sign.y, sign.size / 2]), right, up,
                                                       sign.size / 2, sign.size / 2)
                                     for sign, (right, up, _) in zip(signs, sign_axes, strict=True)]).reshape(-1, 4, 3)
        self._sign_normals = np.array([normal for _, _, normal in sign_axes]).reshape(-1, 3)
        self._sign_centres = self._sign_quads.mean(axis=1) if len(signs) else np.zeros((0, 3))
        self._sign_textures: dict[int, np.ndarray] = {}
        self._light: LightField | None = None
        self._sensor: Sensor | None = None
        if picture is not None and not picture.plain:
            self._light = LightField(world, picture.light_variation, self._rng)
            self._sensor = Sensor(picture, float(self.k[0, 0]), self.width, self.height, self._rng,
                                  colour=self._colour)
            self._marker_light = self._light.at(self._centres[:, :2])
            self._board_light = self._light.at(self._board_centres[:, :2])
            self._obstacle_light = self._light.at(self._obstacle_centres[:, :2])
            self._sign_light = self._light.at(self._sign_centres[:, :2])
            self._noise_bank: list[np.ndarray] = []
            return
        if picture is not None:
            self.noise, self.lighting, self.blur = picture.noise, picture.flicker, picture.blur_px
            noise = picture.noise
        # A bank of noise images drawn once: drawing 300 k normals per frame would cost more
        # than the whole rest of the render.
        shape = (self.height, self.width, 3) if self._colour else (self.height, self.width)
        self._noise_bank = [self._rng.normal(0.0, noise, shape).astype(np.int16) for _ in range(8)]

    @classmethod
    def of_robot(cls, config: RobotConfig, seed: int = 1) -> CameraRenderer:
        """The simulated camera of a robot: its world ``sim.world``, the camera's mount and dictionary,
        the lens ``[sim.lens]`` (not what ``[camera]`` believes: calibrating must find it) and the
        picture of its profile (`icefloe.sim.realism`); ``seed`` for the light, noise and flicker."""
        return cls(load_world(config.sim.world), true_intrinsics(config), Mount.from_config(config.camera),
                   config.camera.dictionary, seed=seed, picture=realism.picture(config))

    @property
    def exposure(self) -> tuple[float, float]:
        """The last frame's shutter time (s) and analogue gain (0, 1 without a realistic picture)."""
        return (self._sensor.shutter_s, self._sensor.gain) if self._sensor else (0.0, 1.0)

    # ------------------------------------------------------------------ drawing

    def _lens(self, intrinsics: Intrinsics) -> tuple[np.ndarray, tuple[int, int], tuple[np.ndarray, ...] | None]:
        """The ideal canvas to draw on (its camera matrix and size) and the remap that bends it
        into the frame; no canvas and no remap for a lens without distortion."""
        if not self.dist.any():
            return self.k, (self.width, self.height), None
        # Where every frame pixel looks, in ideal (undistorted) pixels of the same camera matrix.
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))
        pixels = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-6)
        if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
            ideal = cv2.undistortPointsIter(pixels, self.k, self.dist, None, self.k, criteria)
        else:  # OpenCV 5 took the criteria into undistortPoints
            ideal = cv2.undistortPoints(pixels, self.k, self.dist, R=None, P=self.k, criteria=criteria)
        ideal = ideal.reshape(-1, 2)
        low, high = np.floor(ideal.min(axis=0)) - 2, np.ceil(ideal.max(axis=0)) + 2
        low = np.maximum(low, [-self.width, -self.height])  # a wild lens must not ask for a huge canvas
        high = np.minimum(high, [2 * self.width, 2 * self.height])
        canvas_k = self.k.copy()
        canvas_k[:2, 2] -= low
        size = (int(high[0] - low[0]), int(high[1] - low[1]))
        maps = (ideal - low).astype(np.float32).reshape(self.height, self.width, 2)
        return canvas_k, size, (maps[..., 0].copy(), maps[..., 1].copy())

    def _make_background(self) -> np.ndarray:
        """Plain walls above the horizon, a darker floor below it, with gentle gradients."""
        width, height = self._canvas_size
        horizon = self._canvas_k[1, 2]
        rows = np.arange(height, dtype=np.float32)[:, None]
        wall = 175 + 20 * (rows / height)
        floor = 95 + 40 * ((rows - horizon) / max(height - horizon, 1))
        column = np.where(rows < horizon, wall, floor)
        return np.repeat(column, width, axis=1).clip(0, 255).astype(np.uint8)

    def _texture(self, marker_id: int, cell_px: int) -> np.ndarray:
        """The marker with a one-cell white quiet border, ``cell_px`` pixels per cell (cached)."""
        key = (marker_id, cell_px)
        tex = self._textures.get(key)
        if tex is None:
            inner = cv2.aruco.generateImageMarker(self._dictionary, marker_id, self._cells * cell_px, borderBits=1)
            tex = cv2.copyMakeBorder(inner, cell_px, cell_px, cell_px, cell_px, cv2.BORDER_CONSTANT, value=255)
            self._textures.put(key, tex)
        return tex

    def _project(self, points_camera: np.ndarray, k: np.ndarray | None = None) -> np.ndarray:
        """Camera-frame points (..., 3), m → ideal pinhole pixels (..., 2) of ``k`` (default: the canvas)."""
        k = self._canvas_k if k is None else k
        z = points_camera[..., 2:3]
        uv = points_camera[..., :2] / z
        return uv * [k[0, 0], k[1, 1]] + [k[0, 2], k[1, 2]]

    def _frame_pixels(self, points_camera: np.ndarray) -> np.ndarray:
        """Camera-frame points (n, 3), m → where the lens puts them in the frame, pixels (n, 2)."""
        if self._lens_maps is None:
            return self._project(points_camera, self.k)
        zero = np.zeros(3)
        return cv2.projectPoints(points_camera.reshape(-1, 1, 3), zero, zero, self.k, self.dist)[0].reshape(-1, 2)

    @staticmethod
    def _mip(side_px: float, cells: int, largest: int = 64) -> int:
        """The texture resolution nearest above the on-screen cell size (a mip-map), px per cell:
        warping a much larger texture down would alias the cell edges."""
        cell_px = 2
        while cell_px < largest and cell_px < side_px / cells:
            cell_px *= 2
        return cell_px

    def _draw(self, image: np.ndarray, marker_id: int, quad: np.ndarray, black: np.ndarray,
              light: float = 1.0) -> None:
        """Warp one marker's texture onto ``quad`` (4x2 px), anti-aliased (`_supersampled`), as bright
        as ``light`` (its light over the light auto exposure is set for)."""

        def texture(black_px: np.ndarray) -> np.ndarray:
            side_px = max(np.linalg.norm(black_px[1] - black_px[0]), np.linalg.norm(black_px[3] - black_px[0]))
            tex = self._texture(marker_id, self._mip(side_px, self._cells, 128))
            return tex if light == 1.0 else cv2.convertScaleAbs(tex, alpha=light)

        box_px = float((quad.max(axis=0) - quad.min(axis=0)).max()) + 1
        self._supersampled(image, quad, black, texture, min(SUPERSAMPLE, max(1, int(SUPERSAMPLED_MARKER_PX / box_px))))

    def _draw_board(self, image: np.ndarray, index: int, quad: np.ndarray, light: float = 1.0) -> None:
        """Draw board ``index`` onto ``quad``, anti-aliased (`_supersampled`). Its corners land within
        0.05 px of the truth, and a ChArUco board's marker bits stay readable (a plain warp aliases both)."""
        board = self.world.boards[index]

        def texture(quad_px: np.ndarray) -> np.ndarray:
            side_px = max(np.linalg.norm(quad_px[1] - quad_px[0]) / (board.columns + 2),
                          np.linalg.norm(quad_px[3] - quad_px[0]) / (board.rows + 2))
            cell_px = self._mip(side_px, 1, 128)  # the texture at least as fine as the supersampled picture
            tex = self._board_textures.get((index, cell_px))
            if tex is None:
                tex = board_texture(board, cell_px)
                self._board_textures.put((index, cell_px), tex)
            return tex if light == 1.0 else cv2.convertScaleAbs(tex, alpha=light)

        self._supersampled(image, quad, quad, texture)

    def _supersampled(self, image: np.ndarray, quad: np.ndarray, sized_by: np.ndarray,
                      texture: Callable[[np.ndarray], np.ndarray], f: int = SUPERSAMPLE) -> None:
        """Warp a texture onto ``quad`` (4x2 px: its TL, TR, BR, BL corners) at ``f`` times the
        resolution, then average it down, touching only the quad's bounding box. ``texture`` makes the
        texture for ``sized_by`` (4x2 px) as it lies in the supersampled picture (a mip level of it)."""
        height, width = image.shape[:2]
        x0, y0 = np.floor(quad.min(axis=0)).astype(int)
        x1, y1 = np.ceil(quad.max(axis=0)).astype(int) + 1
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
        if x1 <= x0 or y1 <= y0:
            return
        big = cv2.resize(image[y0:y1, x0:x1], None, fx=f, fy=f, interpolation=cv2.INTER_NEAREST)

        def supersampled(points: np.ndarray) -> np.ndarray:
            # A pixel centre u of the frame is at (u + 0.5) * f - 0.5 in the supersampled picture.
            return (points - [x0, y0] + 0.5) * f - 0.5

        self._warp(big, texture(supersampled(sized_by)), supersampled(quad))
        image[y0:y1, x0:x1] = cv2.resize(big, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)

    def _bbox(self, quad: np.ndarray) -> tuple[int, int, int, int] | None:
        """The canvas pixels (x0, y0, x1, y1: a slice's ends) a polygon (n x 2 px) may touch; None if none."""
        height, width = self._canvas_size[1], self._canvas_size[0]
        x0, y0 = np.floor(quad.min(axis=0)).astype(int)
        x1, y1 = np.ceil(quad.max(axis=0)).astype(int) + 1
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
        return (x0, y0, x1, y1) if x1 > x0 and y1 > y0 else None

    def _inverse_depth(self, normal: np.ndarray, point: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
        """1 / depth (1/m, camera z) of a camera-frame plane at each canvas pixel of ``box``.

        A pixel (u, v) looks along ((u - cx) / fx, (v - cy) / fy, 1); the plane n·p = d meets it at
        depth d / (n·ray), so 1/depth is affine in u and v: one row plus one column per plane."""
        k = self._canvas_k
        d = float(normal @ point)
        if d == 0.0:  # seen edge-on: it covers no pixel
            return np.zeros((box[3] - box[1], box[2] - box[0]), np.float32)
        x0, y0, x1, y1 = box
        du = normal[0] / (k[0, 0] * d)
        dv = normal[1] / (k[1, 1] * d)
        c = (normal[2] - normal[0] * k[0, 2] / k[0, 0] - normal[1] * k[1, 2] / k[1, 1]) / d
        u = np.arange(x0, x1, dtype=np.float32) * np.float32(du)
        v = np.arange(y0, y1, dtype=np.float32) * np.float32(dv) + np.float32(c)
        return v[:, None] + u[None, :]

    @staticmethod
    def _fill(box: tuple[int, int, int, int], polygon: np.ndarray) -> np.ndarray:
        """A boolean mask of ``box`` inside the convex polygon (n x 2 canvas px)."""
        x0, y0, x1, y1 = box
        mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
        points = np.round((polygon - [x0, y0]) * 16).astype(np.int32)  # 4 bits of sub-pixel precision
        cv2.fillConvexPoly(mask, points, 1, cv2.LINE_8, shift=4)
        return mask.view(bool)

    def _draw_obstacles(self, image: np.ndarray, to_camera: Callable[[np.ndarray], np.ndarray],
                        lens: np.ndarray, world_from_camera: np.ndarray,
                        light: np.ndarray | None = None) -> np.ndarray | None:
        """Paint the obstacles' faces that turn towards the lens, the nearest one on each pixel;
        return the depth buffer they leave (1/depth per canvas pixel, 0 where none), None if none.
        ``light``: each face's brightness (its light over the light auto exposure is set for)."""
        if not len(self._obstacles):
            return None
        greys = self._obstacle_greys if light is None else (self._obstacle_greys * light).clip(0, 255).astype(np.uint8)
        facing = np.einsum("ij,ij->i", self._obstacle_normals, lens - self._obstacle_centres) > 0
        corners_c = to_camera(self._obstacles)
        normals_c = self._obstacle_normals @ world_from_camera
        depth = np.zeros((self._canvas_size[1], self._canvas_size[0]), np.float32)
        for i in np.flatnonzero(facing & (corners_c[..., 2] > NEAR).any(axis=1)):
            polygon = clip_near(corners_c[i])
            if len(polygon) < 3:
                continue
            pixels = self._project(polygon)
            box = self._bbox(pixels)
            if box is None:
                continue
            x0, y0, x1, y1 = box
            nearer = self._inverse_depth(normals_c[i], corners_c[i, 0], box)
            seen = depth[y0:y1, x0:x1]
            drawn = self._fill(box, pixels)
            drawn &= nearer > seen
            np.copyto(seen, nearer, where=drawn)  # copyto: masked indexing costs several times more
            where = drawn[..., None] if image.ndim == 3 else drawn
            np.copyto(image[y0:y1, x0:x1], greys[i], where=where)
        return depth

    def _hidden(self, depth: np.ndarray | None, quad: np.ndarray, normal: np.ndarray,
                point: np.ndarray) -> tuple[tuple[int, int, int, int], np.ndarray] | None:
        """Where an obstacle stands in front of a flat thing (its canvas quad, its camera-frame
        plane): its box and the mask of those pixels; None if no obstacle is in its box."""
        if depth is None or (box := self._bbox(quad)) is None:
            return None
        x0, y0, x1, y1 = box
        obstacle = depth[y0:y1, x0:x1]
        if not obstacle.any():
            return None
        mine = self._inverse_depth(normal, point, box)
        # the obstacle is nearer by more than ON_SURFACE: 1/zo > 1/(zm - e)  <=>  izo > izm (1 + e izo)
        return box, obstacle > mine * (1 + ON_SURFACE * obstacle)

    @staticmethod
    def _warp(image: np.ndarray, tex: np.ndarray, quad: np.ndarray) -> None:
        """Warp ``tex`` onto ``quad`` (4x2 px: its TL, TR, BR, BL corners), touching only its bounding box."""
        height, width = image.shape[:2]
        x0, y0 = np.floor(quad.min(axis=0)).astype(int)
        x1, y1 = np.ceil(quad.max(axis=0)).astype(int) + 1
        x0, y0 = max(x0, 0), max(y0, 0)
        x1, y1 = min(x1, width), min(y1, height)
        if x1 <= x0 or y1 <= y0:
            return
        if image.ndim == 3 and tex.ndim == 2:
            tex = cv2.cvtColor(tex, cv2.COLOR_GRAY2BGR)
        th, tw = tex.shape[:2]
        # Pixel centres sit at integer coordinates, so the texture's outer edge is at -0.5 and n-0.5.
        src = np.float32([[-0.5, -0.5], [tw - 0.5, -0.5], [tw - 0.5, th - 0.5], [-0.5, th - 0.5]])
        dst = np.float32(quad - [x0, y0])
        h = cv2.getPerspectiveTransform(src, dst)
        roi = np.ascontiguousarray(image[y0:y1, x0:x1])
        cv2.warpPerspective(tex, h, (x1 - x0, y1 - y0), dst=roi, flags=cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_TRANSPARENT)
        image[y0:y1, x0:x1] = roi

    def _floor_ahead(self, lens: np.ndarray, world_from_camera: np.ndarray) -> np.ndarray:
        """Which canvas pixels look down at the floor in front of the lens, nearer than `FLOOR_FAR`
        (bool, canvas shape): below the horizon. A pixel's ray ((u - cx) / fx, (v - cy) / fy, 1)
        falls by w·ray per metre of depth (w: the world's z in the camera frame), affine in u and v."""
        k, (width, height) = self._canvas_k, self._canvas_size
        w = world_from_camera[2]
        u = np.arange(width, dtype=np.float32) * np.float32(w[0] / k[0, 0])
        v = np.arange(height, dtype=np.float32) * np.float32(w[1] / k[1, 1])
        c = w[2] - w[0] * k[0, 2] / k[0, 0] - w[1] * k[1, 2] / k[1, 1]
        return (v[:, None] + np.float32(c)) + u[None, :] < np.float32(-lens[2] / FLOOR_FAR)

    def _draw_floor(self, image: np.ndarray, lens: np.ndarray, world_from_camera: np.ndarray) -> None:
        """Paint the track's tiles on the floor: its texture warped by the floor plane's homography
        (texture pixel → world (x, y, 0) → canvas), below the horizon only (the homography also maps
        the floor behind the lens, upside down above it). Drawn first: everything else stands on it."""
        ahead = self._floor_ahead(lens, world_from_camera)
        rows = np.flatnonzero(ahead.any(axis=1))
        if not len(rows) or lens[2] <= 0:
            return
        top = int(rows[0])
        camera_from_world = world_from_camera.T
        plane = np.column_stack([camera_from_world[:, 0], camera_from_world[:, 1], -camera_from_world @ lens])
        shift = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, -top], [0.0, 0.0, 1.0]])  # warp only the rows below the top
        h = shift @ self._canvas_k @ plane @ self._world_from_floor
        width, height = self._canvas_size
        warped = cv2.warpPerspective(self._floor, h, (width, height - top), flags=cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0, 0))
        show = ahead[top:] & (warped[..., 3] > 127)
        np.copyto(image[top:], warped[..., :3], where=show[..., None])

    def _draw_sign(self, image: np.ndarray, quad: np.ndarray, light: float = 1.0) -> None:
        """Warp a stop sign's face onto ``quad`` (4x2 canvas px), only inside its octagon, as bright as
        ``light`` (its light over the light auto exposure is set for)."""
        box = self._bbox(quad)
        if box is None:
            return
        side_px = max(np.linalg.norm(quad[1] - quad[0]), np.linalg.norm(quad[3] - quad[0]))
        size = self._mip(side_px, 1, 256)
        tex = self._sign_textures.get(size)
        if tex is None:
            tex = self._sign_textures[size] = stop_sign_texture(size)
        x0, y0, x1, y1 = box
        n = tex.shape[0]
        src = np.float32([[-0.5, -0.5], [n - 0.5, -0.5], [n - 0.5, n - 0.5], [-0.5, n - 0.5]])
        h = cv2.getPerspectiveTransform(src, np.float32(quad - [x0, y0]))
        warped = cv2.warpPerspective(tex, h, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0, 0))
        face = warped[..., :3] if light == 1.0 else cv2.convertScaleAbs(warped[..., :3], alpha=light)
        np.copyto(image[y0:y1, x0:x1], face, where=warped[..., 3:] > 127)

    # ------------------------------------------------------------------ the frame

    def _camera(self, x: float, y: float, theta: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For the robot at pose (x m, y m, theta rad): world_from_robot, the lens position (world)
        and world_from_camera."""
        c, s = math.cos(theta), math.sin(theta)
        world_from_robot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        lens = np.array([x, y, 0.0]) + world_from_robot @ [self.mount.x, self.mount.y, self.mount.z]
        return world_from_robot, lens, world_from_robot @ self.mount.robot_from_camera()

    def render(self, x: float, y: float, theta: float, turn_rate: float = 0.0) -> tuple[np.ndarray, list[Visible]]:
        """One BGR frame (height x width x 3, uint8) seen from the robot at pose (x m, y m, theta rad),
        turning at ``turn_rate`` rad/s (motion blur, with a realistic picture), and the markers fully
        inside it."""
        world_from_robot, lens, world_from_camera = self._camera(x, y, theta)
        robot_origin = np.array([x, y, 0.0])
        # Auto exposure is set for the light where the camera looks (a metre ahead); everything is as
        # bright as its own light against that.
        marker_light = board_light = obstacle_light = sign_light = None
        floor_light = 1.0  # the floor's (and a track's road's) light: where the robot stands
        if self._light is not None:
            view = self._light.at(lens[:2] + world_from_camera[:2, 2])[0]
            marker_light, board_light = self._marker_light / view, self._board_light / view
            obstacle_light, sign_light = self._obstacle_light / view, self._sign_light / view
            floor_light = float(self._light.at(lens[:2])[0] / view)

        def to_camera(points_world: np.ndarray) -> np.ndarray:
            return (points_world - lens) @ world_from_camera  # row vectors: R^T (p - lens)

        quiet_c, black_c = to_camera(self._quiet), to_camera(self._black)
        to_lens = lens - self._centres
        distance = np.linalg.norm(to_lens, axis=1)
        facing = np.einsum("ij,ij->i", self._normals, to_lens) > 0
        in_front = (quiet_c[..., 2] > NEAR).all(axis=1)
        # Boards and markers that face the lens, drawn farthest first.
        drawn = [(float(distance[i]), "marker", int(i)) for i in np.flatnonzero(facing & in_front)]
        boards_c = to_camera(self._board_quads)
        board_to_lens = lens - self._board_centres
        for i in range(len(self.world.boards)):
            if self._board_normals[i] @ board_to_lens[i] > 0 and (boards_c[i, :, 2] > NEAR).all():
                drawn.append((float(np.linalg.norm(board_to_lens[i])), "board", i))
        signs_c = to_camera(self._sign_quads)
        sign_to_lens = lens - self._sign_centres
        for i in range(len(self._sign_quads)):
            if self._sign_normals[i] @ sign_to_lens[i] > 0 and (signs_c[i, :, 2] > NEAR).all():
                drawn.append((float(np.linalg.norm(sign_to_lens[i])), "sign", i))

        image = self._background.copy()
        if self._track is not None:
            self._draw_floor(image, lens, world_from_camera)
        if floor_light != 1.0:
            cv2.convertScaleAbs(image, dst=image, alpha=floor_light)
        depth = self._draw_obstacles(image, to_camera, lens, world_from_camera, obstacle_light)
        normals_c = self._normals @ world_from_camera
        visible: list[Visible] = []
        for _, kind, i in sorted(drawn, reverse=True):
            if kind == "sign":
                quad = self._project(signs_c[i])
                hidden = self._hidden(depth, quad, self._sign_normals[i] @ world_from_camera, signs_c[i, 0])
                before = self._copy(image, hidden)
                self._draw_sign(image, quad, 1.0 if sign_light is None else float(sign_light[i]))
                if hidden is not None and before is not None:
                    self._restore(image, before, *hidden)
                continue
            if kind == "board":
                quad = self._project(boards_c[i])
                hidden = self._hidden(depth, quad, self._board_normals[i] @ world_from_camera, boards_c[i, 0])
                before = self._copy(image, hidden)
                self._draw_board(image, i, quad, 1.0 if board_light is None else float(board_light[i]))
                if hidden is not None and before is not None:
                    self._restore(image, before, *hidden)
                continue
            marker = self._faces[i]
            quiet = self._project(quiet_c[i])
            hidden = self._hidden(depth, quiet, normals_c[i], black_c[i, 0])
            before = self._copy(image, hidden)
            self._draw(image, marker.id, quiet, self._project(black_c[i]),
                       1.0 if marker_light is None else float(marker_light[i]))
            covered = False
            if hidden is not None and before is not None:
                self._restore(image, before, *hidden)
                box, mask = hidden
                covered = bool((mask & self._fill(box, quiet)).any())  # the quiet border too: a detector needs it
            black = self._frame_pixels(black_c[i])
            inside = ((black >= 0) & (black <= [self.width - 1, self.height - 1])).all()
            if inside and not covered:
                rng, bearing = range_bearing(world_from_robot.T @ (self._centres[i] - robot_origin))
                cos_inc = float(self._normals[i] @ to_lens[i]) / distance[i]
                visible.append(Visible(marker.id, rng, bearing, float(distance[i]),
                                       math.acos(min(1.0, cos_inc)), black))
        if self._lens_maps is not None:
            image = cv2.remap(image, *self._lens_maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if self._sensor is not None and self._light is not None:
            return self._sensor.expose(image, turn_rate, float(view), self._light.mean), visible
        return self._finish(image), visible

    @staticmethod
    def _copy(image: np.ndarray, hidden: tuple[tuple[int, int, int, int], np.ndarray] | None) -> np.ndarray | None:
        """The pixels of the box of `_hidden`, as they are before a marker is drawn over them."""
        if hidden is None:
            return None
        x0, y0, x1, y1 = hidden[0]
        return image[y0:y1, x0:x1].copy()

    @staticmethod
    def _restore(image: np.ndarray, before: np.ndarray, box: tuple[int, int, int, int], mask: np.ndarray) -> None:
        """Put back, inside ``box``, the pixels an obstacle hides (``mask``) as they were ``before``."""
        x0, y0, x1, y1 = box
        np.copyto(image[y0:y1, x0:x1], before, where=mask[..., None] if image.ndim == 3 else mask)

    def board_corners(self, x: float, y: float, theta: float) -> list[np.ndarray | None]:
        """Per board of the world: where its inner corners are in the frame seen from pose (x, y, theta),
        ((columns-1) x (rows-1), 2) pixels row by row from its top-left; None if it faces away."""
        _, lens, world_from_camera = self._camera(x, y, theta)
        out: list[np.ndarray | None] = []
        for i, board in enumerate(self.world.boards):
            points = (board_inner_corners(board) - lens) @ world_from_camera
            faces = self._board_normals[i] @ (lens - self._board_centres[i]) > 0
            out.append(self._frame_pixels(points) if faces and (points[:, 2] > NEAR).all() else None)
        return out

    def _finish(self, image: np.ndarray) -> np.ndarray:
        """Lighting change, sensor noise and blur, then grey → BGR like a colour camera's output."""
        gain = 1.0 + self.lighting * self._rng.uniform(-1.0, 1.0)
        if self.blur > 0:
            image = cv2.GaussianBlur(image, (0, 0), self.blur)
        gray = cv2.convertScaleAbs(image, alpha=gain)  # saturates at 0 and 255
        if self.noise > 0:
            noise = self._noise_bank[self._rng.integers(len(self._noise_bank))]
            gray = cv2.add(gray, noise, dtype=cv2.CV_8U)
        return gray if self._colour else cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
