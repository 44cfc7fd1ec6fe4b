"""Roads on the floor: a track of square tiles, as the RVSS workshop lays them ("Need 4 Speed").

A *layout file* is TOML: the tile size and road width, the start line, one ``[[tile]]`` table per
tile and one ``[[sign]]`` table per sign::

    name = "loop"
    tile_size = 0.6           # m, a tile's side
    road_width = 0.3          # m
    start = [0.0, -0.6, 0.0]  # x, y (m), yaw (rad): the start/finish line's centre, the driving direction

    [[tile]]
    kind = "curve"            # straight | curve | corner | t | cross
    col = -2                  # the tile's centre is at (col * tile_size, row * tile_size), world frame
    row = -1
    rotation = 0              # deg, counter-clockwise: 0, 90, 180 or 270
    look = "urban"            # urban (asphalt, lane lines) | rural (a dirt road on grass)

    [[sign]]
    kind = "stop"
    x = 0.6                   # where it stands, m
    y = -0.8
    yaw = 3.14159             # the direction its face looks (towards the traffic it stops), rad
    size = 0.1                # its face's width, m
    stop_x = 0.6              # the stop line on the road in front of it, m
    stop_y = -0.6

Tables rather than rows of tile letters: each tile has a kind, a rotation and a look, which a
grid of letters would need a code per combination (or three grids) for; and a table gives an
error its name (``tile[3].rotation``) as the world files' ``[[marker]]`` tables do.

At rotation 0 each kind's road leaves the tile through these edges (E = +x, N = +y, W, S)::

    straight  W-E                  (a road along x through the centre)
    curve     E-N                  (a quarter circle of radius tile_size / 2 about the NE corner)
    corner    E-N                  (a sharp 90-degree corner: two half straights meeting at the centre)
    t         W-E and N            (a road along x, and one from the centre to N)
    cross     W-E and S-N

and ``rotation`` turns the tile counter-clockwise about its centre. The route a lap drives goes
straight through a T or a crossing; it may not enter a T by its stem (which way would it turn?).

A world file names its track with ``track = "<name or path>"`` (`icefloe.worldmap`): a name is
looked up as worlds are, in a ``tracks/`` folder (``deploy/tracks/`` ships ``loop``); a relative
path is relative to the world file.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Any, Literal

import msgspec
import numpy as np

from . import paths
from .config import field_error, read_toml
from .errors import ConfigError

TileKind = Literal["straight", "curve", "corner", "t", "cross"]
Look = Literal["urban", "rural"]

EDGES = "ENWS"
"""Edge k of a tile lies in the direction k * 90 degrees from its centre."""
CONNECTIONS: dict[str, tuple[int, ...]] = {
    "straight": (0, 2), "curve": (0, 1), "corner": (0, 1), "t": (0, 1, 2), "cross": (0, 1, 2, 3)}
"""The edges (0 = E, 1 = N, 2 = W, 3 = S) each kind's road leaves through, at rotation 0."""
STEP = 0.01
"""The centerline's spacing, m."""
MAX_TILES = 2500
"""More tiles than a sports hall's floor holds (50 x 50): a bigger layout is a mistake."""


class TrackError(ConfigError):
    """A layout file that cannot be a track; the message names the file and the field."""


class Tile(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One square tile of road (a ``[[tile]]`` table)."""

    kind: TileKind
    col: int
    """Its centre is at x = col * tile_size, m."""
    row: int
    """Its centre is at y = row * tile_size, m."""
    rotation: Literal[0, 90, 180, 270] = 0
    """deg, counter-clockwise about its centre."""
    look: Look = "urban"

    def edges(self) -> tuple[int, ...]:
        """The edges its road leaves through, turned by its rotation (0 = E, 1 = N, 2 = W, 3 = S)."""
        return tuple(sorted((e + self.rotation // 90) % 4 for e in CONNECTIONS[self.kind]))


class Sign(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """A flat sign standing on the floor beside the road (a ``[[sign]]`` table), its face's bottom
    edge on the floor."""

    kind: Literal["stop"]
    x: float
    """Where it stands, world frame, m."""
    y: float
    """Where it stands, world frame, m."""
    yaw: float
    """The direction its face looks (towards the traffic it stops), rad, counter-clockwise from +x."""
    size: float = 0.1
    """Its face's width, m."""
    stop_x: float
    """The stop line on the road in front of it (the judge's 10 cm rule), world frame, m."""
    stop_y: float
    """The stop line on the road in front of it, world frame, m."""

    def __post_init__(self) -> None:
        for name in ("x", "y", "yaw", "size", "stop_x", "stop_y"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"`{name}` must be a finite number")
        if not 0 < self.size <= 1.0:
            raise ValueError("`size` must be > 0 and at most 1 m")


def road_mask(kind: str, u: np.ndarray, v: np.ndarray, half_tile: float, half_road: float) -> np.ndarray:
    """Which points (u, v) of a tile at rotation 0 (m, from its centre) are road (bool, u's shape).
    One definition for both `Track.on_road` and the simulator's floor texture."""
    along_x = np.abs(v) <= half_road
    if kind == "straight":
        road = along_x
    elif kind == "curve":
        road = np.abs(np.hypot(u - half_tile, v - half_tile) - half_tile) <= half_road
    elif kind == "corner":
        road = (along_x & (u >= -half_road)) | ((np.abs(u) <= half_road) & (v >= -half_road))
    elif kind == "t":
        road = along_x | ((np.abs(u) <= half_road) & (v >= -half_road))
    else:  # cross
        road = along_x | (np.abs(u) <= half_road)
    edge = half_tile * (1 + 1e-9)  # a point on the edge between two tiles is on both
    return road & (np.abs(u) <= edge) & (np.abs(v) <= edge)


def _direction(edge: int) -> np.ndarray:
    return np.array([math.cos(edge * math.pi / 2), math.sin(edge * math.pi / 2)]).round(12)


def centre_piece(kind: str, entry: int, exit: int, half_tile: float) -> np.ndarray:
    """The road's centre from edge ``entry`` to edge ``exit`` of a tile, (n, 2) m from its centre,
    points `STEP` apart or closer, both ends included."""
    a, b = _direction(entry) * half_tile, _direction(exit) * half_tile
    if (entry - exit) % 4 == 2:  # straight through
        n = max(2, math.ceil(2 * half_tile / STEP) + 1)
        return a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
    if kind == "curve":
        corner = a + b
        start, end = math.atan2(*(a - corner)[::-1]), math.atan2(*(b - corner)[::-1])
        sweep = (end - start + math.pi) % (2 * math.pi) - math.pi  # a quarter turn, either way
        n = max(2, math.ceil(abs(sweep) * half_tile / STEP) + 1)
        angles = start + np.linspace(0.0, sweep, n)
        return corner + half_tile * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    n = max(2, math.ceil(half_tile / STEP) + 1)  # a sharp corner: in to the centre, out again
    t = np.linspace(0.0, 1.0, n)[:, None]
    return np.concatenate([a * (1 - t), b * t[1:]])


class Track(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True, dict=True):
    """A floor of road tiles with signs on it (a layout file). (``dict=True``: room for the cached
    tile grid and centerline: a judge asks `on_road` several times a step.)"""

    name: str = ""
    """Defaults to the layout file's name."""
    tile_size: float
    """A tile's side, m. The workshop's repository gives no dimensions: the shipped layout takes
    0.6 m, the common interlocking floor tile (see deploy/tracks/loop.toml)."""
    road_width: float
    """m."""
    tiles: tuple[Tile, ...] = msgspec.field(name="tile")
    signs: tuple[Sign, ...] = msgspec.field(default=(), name="sign")
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """x, y (m), yaw (rad): the start/finish line's centre and the driving direction."""

    def tile_at(self, x: float, y: float) -> Tile | None:
        """The tile under the point (x, y) (world frame, m), or None."""
        return self._grid().get((math.floor(x / self.tile_size + 0.5), math.floor(y / self.tile_size + 0.5)))

    @functools.cached_property
    def _cells(self) -> dict[tuple[int, int], Tile]:
        return {(t.col, t.row): t for t in self.tiles}

    def _grid(self) -> dict[tuple[int, int], Tile]:
        return self._cells

    def local(self, tile: Tile, x: np.ndarray | float, y: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """World points (m) in the frame of ``tile`` at rotation 0: from its centre, turned back."""
        dx, dy = np.asarray(x) - tile.col * self.tile_size, np.asarray(y) - tile.row * self.tile_size
        a = math.radians(tile.rotation)
        c, s = round(math.cos(a)), round(math.sin(a))
        return c * dx + s * dy, -s * dx + c * dy

    def on_road(self, x: float, y: float) -> bool:
        """Whether the floor at (x, y) (world frame, m) is road."""
        tile = self.tile_at(x, y)
        if tile is None:
            return False
        u, v = self.local(tile, x, y)
        return bool(road_mask(tile.kind, u, v, self.tile_size / 2, self.road_width / 2))

    @staticmethod
    def _through(tile: Tile, entry: int) -> int | None:
        """The edge a lap leaves ``tile`` by, entering by ``entry``: straight on if the road goes
        on, else the one other way; None if there are two other ways (a T entered by its stem)."""
        edges = tile.edges()
        if (entry + 2) % 4 in edges:
            return (entry + 2) % 4
        others = [e for e in edges if e != entry]
        return others[0] if len(others) == 1 else None

    def _start_piece(self, tile: Tile) -> tuple[int, int]:
        """The (entry, exit) edges of the start tile's road that passes the start line's centre
        heading its way. ValueError naming `start` if none does."""
        x, y, yaw = self.start
        heading = np.array([math.cos(yaw), math.sin(yaw)])
        centre = np.array([tile.col, tile.row]) * self.tile_size
        best, score = None, math.cos(math.radians(50))
        for entry in tile.edges():
            exit = self._through(tile, entry)
            if exit is None:
                continue
            piece = centre_piece(tile.kind, entry, exit, self.tile_size / 2) + centre
            gaps = np.hypot(*(piece - [x, y]).T)
            i = int(np.argmin(gaps))
            if gaps[i] > self.road_width / 2:
                continue
            tangent = piece[min(i + 1, len(piece) - 1)] - piece[max(i - 1, 0)]
            along = float(tangent @ heading) / float(np.linalg.norm(tangent))
            if along > score:
                best, score = (entry, exit), along
        if best is None:
            raise ValueError("`start`: its yaw points along none of the start tile's roads")
        return best

    def route(self) -> tuple[list[tuple[Tile, int, int]], bool]:
        """The tiles a lap drives from the start, each with the edge it enters by and leaves by,
        and whether the route closes into a loop. ValueError naming the field if it cannot be driven."""
        grid = self._grid()
        x, y, _ = self.start
        tile = self.tile_at(x, y)
        if tile is None or not self.on_road(x, y):
            raise ValueError("`start`: the start line's centre is not on the road")
        entry, exit = self._start_piece(tile)
        route: list[tuple[Tile, int, int]] = [(tile, entry, exit)]
        seen = {(tile.col, tile.row, entry)}
        while True:
            d = _direction(exit).round().astype(int)
            nxt = grid.get((tile.col + int(d[0]), tile.row + int(d[1])))
            entry = (exit + 2) % 4
            if nxt is None or entry not in nxt.edges():
                return route, False
            if (nxt.col, nxt.row, entry) in seen:
                return route, (nxt.col, nxt.row, entry) == (route[0][0].col, route[0][0].row, route[0][1])
            tile = nxt
            through = self._through(tile, entry)
            if through is None:
                i = self.tiles.index(tile)
                raise ValueError(f"`tile[{i}]`: the route enters this T by its stem (col {tile.col}, "
                                 f"row {tile.row}): which way it turns is not defined")
            exit = through
            seen.add((tile.col, tile.row, entry))
            route.append((tile, entry, exit))

    def centerline(self) -> np.ndarray:
        """The road's centre (N, 2), world m, in driving order from the start line's centre (its
        projection on the road's centre); closed (the last point is the first) if a loop.
        Points at most `STEP` apart; read-only (computed once)."""
        return self._centerline

    @functools.cached_property
    def _centerline(self) -> np.ndarray:
        route, closed = self.route()
        pieces = []
        for tile, entry, exit in route:
            piece = centre_piece(tile.kind, entry, exit, self.tile_size / 2)
            pieces.append((piece if not pieces else piece[1:]) + [tile.col * self.tile_size, tile.row * self.tile_size])
        line = np.concatenate(pieces)
        start = int(np.argmin(np.hypot(*(line - self.start[:2]).T)))
        line = np.concatenate([line[start:-1], line[:start + 1]]) if closed else line[start:]
        line.flags.writeable = False
        return line

    def lap_length(self) -> float:
        """The centerline's length, m."""
        return float(np.hypot(*np.diff(self.centerline(), axis=0).T).sum())


def parse_track(data: dict[str, Any], source: str) -> Track:
    """A Track from a TOML-shaped dict; `TrackError` names ``source`` and the field."""
    try:
        track = msgspec.convert(data, Track)
    except msgspec.ValidationError as exc:
        raise TrackError(field_error(source, exc)) from None
    for name in ("tile_size", "road_width"):
        value = getattr(track, name)
        if not (math.isfinite(value) and 0 < value <= 10):
            raise TrackError(f"{source}: {name}: must be > 0 and at most 10 m, got {value}")
    if track.road_width >= track.tile_size:
        raise TrackError(f"{source}: road_width: {track.road_width} m must be less than tile_size "
                         f"({track.tile_size} m)")
    if not all(math.isfinite(v) for v in track.start):
        raise TrackError(f"{source}: start: must be three finite numbers: x, y (m), yaw (rad)")
    if not 0 < len(track.tiles) <= MAX_TILES:
        raise TrackError(f"{source}: tile: a track needs 1 to {MAX_TILES} [[tile]] tables, "
                         f"got {len(track.tiles)}")
    first: dict[tuple[int, int], int] = {}
    for i, tile in enumerate(track.tiles):
        if abs(tile.col) > 1000 or abs(tile.row) > 1000:
            raise TrackError(f"{source}: tile[{i}].col: col and row must be within ±1000")
        if (tile.col, tile.row) in first:
            raise TrackError(f"{source}: tile[{i}].col: col {tile.col}, row {tile.row} is already "
                             f"tile[{first[tile.col, tile.row]}]")
        first[tile.col, tile.row] = i
    for i, sign in enumerate(track.signs):
        if not track.on_road(sign.stop_x, sign.stop_y):
            raise TrackError(f"{source}: sign[{i}].stop_x: the stop line ({sign.stop_x}, {sign.stop_y}) "
                             "is not on the road")
    try:
        track.route()
    except ValueError as exc:
        raise TrackError(f"{source}: {str(exc).replace('`', '')}") from None
    return track if track.name else msgspec.structs.replace(track, name=Path(source).stem)


def find_track(name_or_path: str, relative_to: Path | None = None) -> Path:
    """The layout file a name (looked up in the ``tracks`` folders, as worlds are) or a path means;
    a relative path is taken from ``relative_to`` (a world file's folder) if given."""
    text = str(name_or_path)
    if not paths.is_path(text):
        return paths.find("tracks", text, "track layout")
    path = Path(text).expanduser()
    if relative_to is not None and not path.is_absolute():
        path = relative_to / path
    return paths.find("tracks", str(path), "track layout")


def load_track(name_or_path: str, relative_to: Path | None = None) -> Track:
    """Load a layout file (a name, or a path); `TrackError` names the file and the field."""
    try:
        path = find_track(name_or_path, relative_to)
        data = read_toml(path, "track layout")
    except ConfigError as exc:
        raise TrackError(str(exc)) from None
    return parse_track(data, str(path))
