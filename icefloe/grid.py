"""The occupancy grid: a world's obstacles (`icefloe.worldmap`) as square cells, for a planner.

A `Grid` is a NumPy array of cells, ``cells[row, col]``, 1 = occupied, 0 = free, with row 0 at
the *bottom* (``y = origin_y``) and column 0 at the left (``x = origin_x``): the cell ``(row,
col)`` covers x in ``origin_x + [col, col + 1) * resolution`` and y likewise with ``row``. That
is ``occgrid[y, x]``, the orientation the Robotics Toolbox's planners take.

A cell is occupied when any part of it may touch an obstacle (its centre lies within the
obstacle grown by half a cell), so a path through free cells never grazes a wall. `inflate`
grows the obstacles by the robot's radius: then the robot's *centre* may go wherever a cell is
free, which is what a planner that treats the robot as a point wants.

Files: ``.npz`` keeps everything (cells, resolution, origin, inflation, world); ``.npy`` the
cells alone (as the toolbox takes them); ``.png`` a picture of them, white free and black
occupied, north up (row 0 is the picture's *bottom* line). `icefloe grid` writes them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .config import RobotConfig
from .errors import ConfigError
from .worldmap import WorldMap

FREE, OCCUPIED = 0, 1
MAX_CELLS = 4_000_000
"""Largest grid made (2000 x 2000 cells: a 40 m room at 2 cm), so a typo cannot fill the memory."""
DEFAULT_EXTENT = 2.0
"""Half the side of the area of a world with no obstacles and no markers, m."""


@dataclass(frozen=True)
class Grid:
    cells: np.ndarray
    """uint8 (rows, cols): 1 occupied, 0 free; row 0 at y = origin_y."""
    resolution: float
    """Side of a cell, m."""
    origin_x: float
    """World x of the left edge of column 0, m."""
    origin_y: float
    """World y of the bottom edge of row 0, m."""
    inflation: float = 0.0
    """The obstacles were grown by this much, m (0: as they stand)."""
    world: str = ""

    @property
    def shape(self) -> tuple[int, int]:
        return self.cells.shape  # type: ignore[return-value]

    def cell(self, x: float, y: float) -> tuple[int, int]:
        """(row, col) of the cell holding the point (x, y) (it may be outside the grid)."""
        return (math.floor((y - self.origin_y) / self.resolution), math.floor((x - self.origin_x) / self.resolution))

    def centre(self, row: int, col: int) -> tuple[float, float]:
        """World (x, y) of a cell's centre, m."""
        return (self.origin_x + (col + 0.5) * self.resolution, self.origin_y + (row + 0.5) * self.resolution)

    def contains(self, row: int, col: int) -> bool:
        return 0 <= row < self.cells.shape[0] and 0 <= col < self.cells.shape[1]

    def free(self, row: int, col: int) -> bool:
        """Is the cell in the grid and free?"""
        return self.contains(row, col) and self.cells[row, col] == FREE

    def inflate(self, radius: float) -> Grid:
        """The obstacles grown by ``radius`` m: every cell whose centre is within ``radius`` of an
        occupied cell's centre becomes occupied (the free space a point robot may use)."""
        if radius <= 0:
            return self
        import cv2  # the distance transform (exact Euclidean, DIST_MASK_PRECISE)

        free = (self.cells == FREE).astype(np.uint8)
        distance = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * self.resolution
        cells = np.where(distance <= radius, OCCUPIED, FREE).astype(np.uint8)
        return replace(self, cells=cells, inflation=self.inflation + radius)

    # ------------------------------------------------------------------ files

    def save(self, path: str | Path) -> Path:
        """Write ``.npz`` (everything), ``.npy`` (the cells) or ``.png`` (a picture, north up)."""
        path = Path(path).expanduser()
        suffix = path.suffix.lower()
        if suffix == ".npz":
            np.savez_compressed(path, cells=self.cells, resolution=self.resolution,
                                origin=(self.origin_x, self.origin_y),
                                inflation=self.inflation, world=self.world)
        elif suffix == ".npy":
            np.save(path, self.cells)
        elif suffix == ".png":
            import cv2

            picture = np.where(self.cells[::-1] == FREE, 255, 0).astype(np.uint8)
            if not cv2.imwrite(str(path), picture):
                raise OSError(f"{path}: OpenCV could not write the picture")
        else:
            raise ValueError(f"{path}: write .png, .npy or .npz (not {suffix or 'no suffix'!r})")
        return path


def load(path: str | Path, resolution: float = 0.0, origin: tuple[float, float] = (0.0, 0.0)) -> Grid:
    """Read a grid file: ``.npz`` as written by `Grid.save`; ``.npy`` or ``.png`` (black = occupied)
    need ``resolution`` (m) and ``origin`` (x, y of the bottom-left corner, m). ValueError names
    the file and what is wrong."""
    path = Path(path).expanduser()
    suffix = path.suffix.lower()
    try:
        if suffix == ".npz":
            with np.load(path, allow_pickle=False) as data:
                ox, oy = (float(v) for v in data["origin"])
                return _checked(path, data["cells"], float(data["resolution"]), ox, oy,
                                float(data["inflation"]), str(data["world"]))
        if suffix == ".npy":
            cells = np.load(path, allow_pickle=False)
        elif suffix == ".png":
            import cv2

            picture = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if picture is None:
                raise ValueError("not a picture OpenCV can read")
            cells = np.where(picture[::-1] >= 128, FREE, OCCUPIED)
        else:
            raise ValueError(f"read .png, .npy or .npz (not {suffix or 'no suffix'!r})")
    except (OSError, KeyError, ValueError) as exc:
        raise ValueError(f"{path}: {exc}") from None
    return _checked(path, cells, resolution, *origin, 0.0, path.stem)


def _checked(path: Path, cells: np.ndarray, resolution: float, ox: float, oy: float, inflation: float,
             world: str) -> Grid:
    if cells.ndim != 2 or cells.size == 0 or cells.size > MAX_CELLS:
        raise ValueError(f"{path}: the cells must be a 2-D array of 1 to {MAX_CELLS} cells, not shape {cells.shape}")
    if not np.isin(cells, (FREE, OCCUPIED)).all():
        raise ValueError(f"{path}: cells must be 0 (free) or 1 (occupied)")
    if not (math.isfinite(resolution) and resolution > 0):
        raise ValueError(f"{path}: the resolution must be a number of metres > 0 (give it for .png and .npy)")
    if not all(math.isfinite(v) for v in (ox, oy, inflation)):
        raise ValueError(f"{path}: the origin and inflation must be finite numbers")
    return Grid(cells.astype(np.uint8), resolution, ox, oy, inflation, world)


# ---------------------------------------------------------------------- from a world


def bounds(world: WorldMap) -> tuple[float, float, float, float]:
    """(x_min, y_min, x_max, y_max) m: around the obstacles (or, without any, the markers)."""
    xs: list[float] = []
    ys: list[float] = []
    for o in world.obstacles:
        cx, cy, hl, hw, yaw = o.rectangle()
        c, s = math.cos(yaw), math.sin(yaw)
        for u, v in ((hl, hw), (hl, -hw), (-hl, hw), (-hl, -hw)):   # the corners
            xs.append(cx + u * c - v * s)
            ys.append(cy + u * s + v * c)
    if not xs:
        xs = [mk.x for mk in world.markers]
        ys = [mk.y for mk in world.markers]
    if not xs:
        return (-DEFAULT_EXTENT, -DEFAULT_EXTENT, DEFAULT_EXTENT, DEFAULT_EXTENT)
    return (min(xs), min(ys), max(xs), max(ys))


def from_world(world: WorldMap, resolution: float) -> Grid:
    """The world's obstacles as a grid of ``resolution`` m cells, covering `bounds` (one cell more
    on each side). ValueError for a resolution that is not > 0 or a grid of over `MAX_CELLS`."""
    if not (math.isfinite(resolution) and resolution > 0):
        raise ValueError(f"grid resolution must be a number of metres > 0, got {resolution}")
    x0, y0, x1, y1 = bounds(world)
    # the origin on a multiple of the resolution, so grids of one world at one resolution agree
    ox, oy = math.floor(x0 / resolution - 1) * resolution, math.floor(y0 / resolution - 1) * resolution
    cols, rows = math.ceil((x1 - ox) / resolution) + 1, math.ceil((y1 - oy) / resolution) + 1
    if rows * cols > MAX_CELLS:
        raise ValueError(f"world {world.name}: a grid of {cols} x {rows} cells at {resolution} m is more than "
                         f"{MAX_CELLS} cells; use a coarser resolution")
    xs = ox + (np.arange(cols) + 0.5) * resolution
    ys = oy + (np.arange(rows) + 0.5) * resolution
    x, y = np.meshgrid(xs, ys)                      # (rows, cols): cell centres
    cells = np.zeros((rows, cols), np.uint8)
    half = resolution / 2
    for o in world.obstacles:
        cx, cy, hl, hw, yaw = o.rectangle()
        c, s = math.cos(yaw), math.sin(yaw)
        u, v = (x - cx) * c + (y - cy) * s, -(x - cx) * s + (y - cy) * c   # in the obstacle's frame
        # grown by half a cell along the cell's own axes, seen in the obstacle's frame
        gu, gv = half * (abs(c) + abs(s)), half * (abs(c) + abs(s))
        cells[(np.abs(u) <= hl + gu) & (np.abs(v) <= hw + gv)] = OCCUPIED
    return Grid(cells, resolution, ox, oy, 0.0, world.name)


def of_robot(config: RobotConfig) -> Grid:
    """The grid of a robot's world (``planner.world``, else ``localizer.world``) at its
    ``planner.resolution``, not inflated; `ConfigError` names the key if it cannot be made."""
    from .worldmap import load_world

    name = config.planner.world or config.localizer.world
    try:
        return from_world(load_world(name), config.planner.resolution)
    except ValueError as exc:
        raise ConfigError(f"{config.source}: planner.resolution: {exc}") from None
