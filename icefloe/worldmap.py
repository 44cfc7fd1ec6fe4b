"""The world map: where the ArUco landmarks are.

A world file is TOML in ``deploy/worlds/`` with one ``[[marker]]`` table per
marker::

    name = "lab"              # optional; defaults to the file name

    [[marker]]
    id = 0                    # ArUco id in the robot's dictionary (camera.dictionary)
    x = 2.0                   # centre of the marker in the world frame, m
    y = -1.2
    z = 0.10                  # height of the centre above the floor, m
    size = 0.15               # side of the black square, m (the white border is extra)
    yaw = 3.14159             # direction the printed face points, rad, CCW from +x

The simulator renders these markers, the camera service takes each marker's
size from here (to measure its distance), and the localizer uses the positions.

A world may also stand calibration boards in it, for `icefloe calibrate` in the
simulator (only the simulator's camera sees them; see `Board`)::

    [[board]]
    kind = "chessboard"       # or "charuco"
    columns = 10              # squares across (a chessboard has columns - 1 inner corners)
    rows = 7                  # squares down
    square = 0.025            # side of a square, m
    x = 0.5                   # centre of the board, m
    y = 0.0
    z = 0.12
    yaw = 3.14159             # direction the printed face points, rad, CCW from +x
    tilt = 0.35               # leaning back by this, rad (top edge away from the viewer)

A world may also lie ArUco markers flat on the floor, for the lab's overhead camera to find
its own pose from (``icefloe extloc calibrate``, docs/extloc.md; the robots' cameras ignore them)::

    [[floor_marker]]
    id = 80                   # ArUco id in the overhead camera's dictionary (overhead.dictionary)
    x = 1.7                   # centre of the marker on the floor, world frame, m
    y = -1.7
    size = 0.2                # side of the black square, m
    yaw = 0.0                 # where the marker's top edge points, rad, CCW from +x

Obstacles stand on the floor: the simulated robot collides with them and stops
(`icefloe.sim.world`), and the occupancy grid a planner uses is made from them
(`icefloe.grid`). Two kinds, each a rectangle seen from above::

    [[obstacle]]
    kind = "wall"             # a straight wall from (x0, y0) to (x1, y1)
    x0 = -2.0                 # m
    y0 = 2.0
    x1 = 2.0
    y1 = 2.0
    thickness = 0.05          # m, centred on the line (default 0.05)
    height = 0.3              # m (default 0.3)

    [[obstacle]]
    kind = "box"              # a box centred on (x, y)
    x = -0.9                  # m
    y = -0.9
    length = 0.5              # m, along yaw
    width = 0.4               # m, across yaw
    yaw = 0.0                 # rad, CCW from +x (default 0)
    height = 0.3              # m (default 0.3)

A world may also hold marker blocks: one id printed on several vertical faces of a cube, as
courses print them (the same marker on four sides, so the robot sees it from anywhere)::

    [[block]]
    id = 12                   # ArUco id on every face (no other marker or block may use it)
    x = 0.8                   # centre of the cube, m
    y = 0.4
    z = 0.10                  # height of the markers' centres (the cube's middle), m
    side = 0.16               # edge of the cube, m
    size = 0.12               # side of the black square on each face, m (less than `side`)
    yaw = 0.0                 # direction face 0 points, rad; faces 1, 2, 3 turn by 90° each
    faces = 4                 # how many faces carry the marker (1-4, counter-clockwise from face 0)

A block is ONE landmark, at the cube's centre: the simulator renders each face
(`WorldMap.faces`), the camera reports each face it sees (an id may then appear twice in one
frame), and the localizer moves each sighting from the face to the cube's centre along that
face's normal, merges the faces of one frame into one sighting, and uses it as a landmark at
(x, y) (`WorldMap.landmarks`; docs/sim.md).

A world may lay a road on its floor, a track of tiles with signs (`icefloe.track`: a layout
file, looked up by name in a ``tracks/`` folder as worlds are, or a path relative to the world file)::

    track = "loop"            # deploy/tracks/loop.toml

World frame: x and y on the floor, z up, angles counter-clockwise from +x.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import msgspec

from . import paths
from .config import field_error, read_toml
from .errors import ConfigError
from .track import Track, load_track


def check_finite(item: msgspec.Struct, names: Iterable[str]) -> None:
    """ValueError naming the first field of ``names`` that is not a finite number (TOML has nan and inf)."""
    for name in names:
        if not math.isfinite(getattr(item, name)):
            raise ValueError(f"`{name}` must be a finite number")


def check_positive(item: msgspec.Struct, *names: str) -> None:
    """ValueError naming the fields of ``names`` if any is not > 0 (a size)."""
    if any(getattr(item, name) <= 0 for name in names):
        raise ValueError(f"{' and '.join(f'`{name}`' for name in names)} must be > 0")



class Marker(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One ArUco marker fixed in the world."""

    id: Annotated[int, msgspec.Meta(ge=0)]
    x: float
    """Centre, world frame, m."""
    y: float
    """Centre, world frame, m."""
    z: float
    """Height of the marker's centre above the floor, m."""
    size: Annotated[float, msgspec.Meta(gt=0)]
    """Side of the black square, m."""
    yaw: float
    """Direction the marker's face points, rad, counter-clockwise from +x."""

    def __post_init__(self) -> None:
        check_finite(self, ("x", "y", "z", "size", "yaw"))


class Board(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A camera calibration board standing in the world (a ``[[board]]`` table), printed with a
    white margin of one square; ``icefloe calibrate --board ...`` must be told the same sizes."""

    columns: Annotated[int, msgspec.Meta(ge=3, le=40)]
    """Squares across."""
    rows: Annotated[int, msgspec.Meta(ge=3, le=40)]
    """Squares down."""
    square: Annotated[float, msgspec.Meta(gt=0)]
    """Side of a square, m."""
    x: float
    """Centre, world frame, m."""
    y: float
    z: float
    """Height of the centre above the floor, m."""
    yaw: float
    """Direction the printed face points, rad, counter-clockwise from +x."""
    tilt: float = 0.0
    """Leaning back by this, rad: the top edge away from whoever faces it."""
    kind: Literal["chessboard", "charuco"] = "chessboard"
    marker: float = 0.0
    """ChArUco: side of each ArUco marker, m (less than ``square``)."""
    dictionary: str = "DICT_5X5_100"
    """ChArUco: the markers' dictionary. Not the landmarks' ids: the localizer must not take them for
    landmarks (another dictionary, or the landmarks' with a ``first_id`` beyond the world's)."""
    first_id: Annotated[int, msgspec.Meta(ge=0, le=999)] = 0
    """ChArUco: the id of its first marker (the others follow)."""

    def __post_init__(self) -> None:
        check_finite(self, ("square", "x", "y", "z", "yaw", "tilt", "marker"))
        if self.kind == "charuco" and not 0 < self.marker < self.square:
            raise ValueError("`marker` must be > 0 and smaller than `square` for a charuco board")


class FloorMarker(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """An ArUco marker lying flat on the floor (a ``[[floor_marker]]`` table), seen from above."""

    id: Annotated[int, msgspec.Meta(ge=0)]
    x: float
    """Centre, world frame, m."""
    y: float
    """Centre, world frame, m."""
    size: Annotated[float, msgspec.Meta(gt=0)]
    """Side of the black square, m."""
    yaw: float = 0.0
    """Where the marker's top edge points, rad, counter-clockwise from +x."""

    def __post_init__(self) -> None:
        check_finite(self, ("x", "y", "size", "yaw"))


Rectangle = tuple[float, float, float, float, float]
"""An obstacle's footprint: centre x, centre y (m), half length along yaw, half width (m), yaw (rad)."""


class _Obstacle(msgspec.Struct, frozen=True, forbid_unknown_fields=True, tag_field="kind", kw_only=True):
    height: float = 0.3
    """m. (Keyword-only: it comes after the fields of each kind, as written in a world file.)"""
    sizes: ClassVar[tuple[str, ...]] = ()
    """The kind's fields that must be > 0, as ``height`` must."""

    def __post_init__(self) -> None:
        check_finite(self, self.__struct_fields__)
        check_positive(self, "height")
        check_positive(self, *self.sizes)

    def rectangle(self) -> Rectangle:
        """The obstacle's footprint on the floor."""
        raise NotImplementedError


class Wall(_Obstacle, frozen=True, tag="wall"):
    """A straight wall from (x0, y0) to (x1, y1), ``thickness`` thick (centred on the line)."""

    x0: float
    """One end, world frame, m."""
    y0: float
    x1: float
    """The other end, world frame, m."""
    y1: float
    thickness: float = 0.05
    """m."""
    sizes = ("thickness",)

    def __post_init__(self) -> None:
        super().__post_init__()
        if math.hypot(self.x1 - self.x0, self.y1 - self.y0) == 0:
            raise ValueError("the wall's two ends (x0, y0) and (x1, y1) are the same point")

    def rectangle(self) -> Rectangle:
        length = math.hypot(self.x1 - self.x0, self.y1 - self.y0)
        return ((self.x0 + self.x1) / 2, (self.y0 + self.y1) / 2, length / 2, self.thickness / 2,
                math.atan2(self.y1 - self.y0, self.x1 - self.x0))


class Box(_Obstacle, frozen=True, tag="box"):
    """A box centred on (x, y), ``length`` along ``yaw`` and ``width`` across it."""

    x: float
    """Centre, world frame, m."""
    y: float
    length: float
    """m, along yaw."""
    width: float
    """m, across yaw."""
    yaw: float = 0.0
    """rad, counter-clockwise from +x."""
    sizes = ("length", "width")

    def rectangle(self) -> Rectangle:
        return (self.x, self.y, self.length / 2, self.width / 2, self.yaw)


Obstacle = Wall | Box


def clearance(rect: Rectangle, x: float, y: float) -> float:
    """Distance from the point (x, y) to the rectangle, m (0 inside it)."""
    cx, cy, hl, hw, yaw = rect
    c, s = math.cos(yaw), math.sin(yaw)
    u, v = (x - cx) * c + (y - cy) * s, -(x - cx) * s + (y - cy) * c   # in the rectangle's frame
    du, dv = max(abs(u) - hl, 0.0), max(abs(v) - hw, 0.0)
    return math.hypot(du, dv)


class Block(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A cube with the same marker on up to four vertical faces (a ``[[block]]`` table): one landmark."""

    id: Annotated[int, msgspec.Meta(ge=0)]
    x: float
    """Centre of the cube, world frame, m."""
    y: float
    """Centre of the cube, world frame, m."""
    z: float
    """Height of the markers' centres above the floor, m."""
    side: Annotated[float, msgspec.Meta(gt=0)]
    """Edge of the cube, m."""
    size: Annotated[float, msgspec.Meta(gt=0)]
    """Side of the black square on each face, m (less than ``side``)."""
    yaw: float = 0.0
    """Direction face 0 points, rad, counter-clockwise from +x; face k points yaw + k·90°."""
    faces: Annotated[int, msgspec.Meta(ge=1, le=4)] = 4
    """Faces that carry the marker, counter-clockwise from face 0."""

    def __post_init__(self) -> None:
        check_finite(self, ("x", "y", "z", "side", "size", "yaw"))
        if self.size >= self.side:
            raise ValueError(f"`size` ({self.size} m) must be less than `side` ({self.side} m): "
                             "the marker is printed on a face of the cube")

    def face_markers(self) -> tuple[Marker, ...]:
        """Each printed face as a `Marker`: at the face's centre, facing out."""
        out = []
        for k in range(self.faces):
            yaw = self.yaw + k * math.pi / 2
            out.append(Marker(id=self.id, x=self.x + self.side / 2 * math.cos(yaw),
                              y=self.y + self.side / 2 * math.sin(yaw), z=self.z, size=self.size, yaw=yaw))
        return tuple(out)


class WorldMap(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A named set of markers and marker blocks, each id used once (a world file: ``name``,
    ``[[marker]]`` and ``[[block]]`` tables), the calibration boards standing in it (``[[board]]``),
    the markers on its floor for an overhead camera (``[[floor_marker]]``) and its obstacles
    (``[[obstacle]]``)."""

    name: str = ""
    markers: tuple[Marker, ...] = msgspec.field(default=(), name="marker")
    boards: tuple[Board, ...] = msgspec.field(default=(), name="board")
    blocks: tuple[Block, ...] = msgspec.field(default=(), name="block")
    floor_markers: tuple[FloorMarker, ...] = msgspec.field(default=(), name="floor_marker")
    obstacles: tuple[Obstacle, ...] = msgspec.field(default=(), name="obstacle")
    track: Track | None = None
    """The road on the floor, from the layout file the world file's ``track`` key names."""

    def clearance(self, x: float, y: float) -> float:
        """Distance from (x, y) to the nearest obstacle, m (0 inside one; inf without obstacles)."""
        return min((clearance(o.rectangle(), x, y) for o in self.obstacles), default=math.inf)

    def marker(self, id: int) -> Marker | None:
        """The marker (a ``[[marker]]``) with this ArUco id, or None if the world has none."""
        return next((m for m in self.markers if m.id == id), None)

    def block(self, id: int) -> Block | None:
        """The block with this ArUco id, or None."""
        return next((b for b in self.blocks if b.id == id), None)

    def faces(self) -> tuple[Marker, ...]:
        """Every printed marker: the ``[[marker]]``s, then each face of each block (an id repeats
        within a block). What a camera can see: the simulator renders these."""
        return self.markers + tuple(f for b in self.blocks for f in b.face_markers())

    def landmarks(self) -> dict[int, tuple[float, float]]:
        """One position per id, world frame (x, y) in m: each marker's centre, each block's centre."""
        return {**{m.id: (m.x, m.y) for m in self.markers}, **{b.id: (b.x, b.y) for b in self.blocks}}

    def sizes(self) -> dict[int, float]:
        """The black square's side per id, m (the camera measures distance with it)."""
        return {f.id: f.size for f in self.faces()}


def parse_world(data: dict[str, Any], source: str) -> WorldMap:
    """A WorldMap from a TOML-shaped dict; `ConfigError` names ``source``, the marker and the key
    (a bad layout file: its own name and field)."""
    data = dict(data)
    track_name = data.pop("track", None)
    try:
        world = msgspec.convert(data, WorldMap)
    except msgspec.ValidationError as exc:
        raise ConfigError(field_error(source, exc)) from None
    first: dict[int, str] = {}
    for table, items in (("marker", world.markers), ("block", world.blocks)):
        for i, item in enumerate(items):
            if item.id in first:
                raise ConfigError(f"{source}: {table}[{i}].id: id {item.id} is already used by "
                                  f"{first[item.id]} (one id is one landmark: to print it on several "
                                  "faces, make it a [[block]])")
            first[item.id] = f"{table}[{i}]"
    floor: dict[int, int] = {}
    for i, f in enumerate(world.floor_markers):
        if f.id in floor:
            raise ConfigError(f"{source}: floor_marker[{i}].id: id {f.id} is already used by "
                              f"floor_marker[{floor[f.id]}]")
        floor[f.id] = i
    if track_name is not None:
        if not isinstance(track_name, str) or not track_name:
            raise ConfigError(f"{source}: track: must be the name of a track layout or a path to one")
        world = msgspec.structs.replace(world, track=load_track(track_name, Path(source).parent))
    return world if world.name else msgspec.structs.replace(world, name=Path(source).stem)


def load_world(name_or_path: str) -> WorldMap:
    """Load a world file: a name (``"lab"``, or ``"lab.toml"`` as robot configs write it) is
    looked up like a robot's (`icefloe.paths`: yours, the machine's, the shipped ones); a path is that file."""
    text = str(name_or_path)
    if "/" not in text and not text.startswith("~"):
        text = text.removesuffix(".toml")
    path = paths.find("worlds", text, "world file")
    return parse_world(read_toml(path, "world file"), str(path))
