"""Bus messages -> Rerun archetypes, for one robot.

`RobotLogger` turns each icefloe message into Rerun log calls under the robot's
own entity path, ``/robots/<name>/...``, so several robots can share one viewer:

=================================  ==========================================  =====================
entity (under /robots/<name>)      what                                        from
=================================  ==========================================  =====================
map                                y flip: the map reads x right, y up (static)
map/landmarks                      the world file's markers (static)           localizer.world
map/odom, map/odom/trail           pose arrow and the path driven              odom/pose
map/loc, map/loc/covariance        pose arrow and its 95 % ellipse             loc/pose
map/truth, map/truth/trail         the simulator's true pose                   sim/truth
map/car, map/car/trail             the virtual car: its body, its front wheels car/state
                                   at the steering angle, at its bicycle-model
                                   pose (odometry's frame), and its path
map/reference                      the map maker's landmarks, 95 % ellipses    map/landmarks
map/slam, map/slam/covariance      SLAM's pose arrow and its 95 % ellipse      slam/pose
map/slam/landmarks                 SLAM's landmarks, 95 % ellipses             slam/map
map/rays                           a line to each marker seen in this frame    camera/landmarks
map/obstacles                      the world file's walls and boxes (static)   localizer.world
map/grid                           the occupancy grid, a cell per pixel        map/grid (a query)
map/path                           the path the follower drives ([] clears)    nav/path
log/nav                            the follower's state, on each change        nav/status
map/judge/penalties                the lap judge's penalties where they        judge/state
                                   happened, labelled (cleared at a lap start)
judge/{lap_time,penalties}         the lap in progress: time, penalty s        judge/state
judge/lap                          the lap in words (a text document)          judge/state
log/judge                          each lap's result, each penalty             judge/lap, judge/state
camera/image, camera/image/markers the JPEG and the detected marker outlines   camera/image, .../landmarks
oled                               the little screen, one pixel per pixel      oled/frame
wheels/{left,right}/{target,measured}  commanded vs measured rim speed, m/s    hw/wheels
battery/{voltage,current}/{filtered,raw}  V and A                              power/battery, hw/battery
loop/latency_ms/{p50,p99,p999,max} hwbridge wake-up latency, ms                hw/loop
loop/errors/{overruns,link_errors} counts since start                          hw/loop
log                                log lines of every service                  log
=================================  ==========================================  =====================

Every message is logged at its own ``stamp`` on the ``stamp`` timeline, so what
you scrub through is robot time, not the time the laptop happened to receive it.
(``oled/frame`` has no stamp; it is logged at the time it arrived.)

The geometry helpers (`covariance_ellipse`, `ray_ends`, `unpack_oled`, ...)
are plain functions of numbers, so they are tested without Rerun or Zenoh.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Sequence

import numpy as np
import rerun as rr

from icefloe.grid import FREE, MAX_CELLS, OCCUPIED, Grid
from icefloe.schemas import messages as m
from icefloe.worldmap import Rectangle

from .decimate import Decimator

TIMELINE = "stamp"
MAP_FLIP = (1.0, -1.0, 1.0)
"""Scale of ``map`` relative to the robot's root. Rerun's 2D views put +y down; the map view is
rooted one level up (``blueprint.py``), so this flip makes the world's +y point up on screen and
an anticlockwise turn look anticlockwise. Logged values stay in world coordinates."""
ARROW_LENGTH = 0.12
"""Length of a pose arrow on the map, m (a little less than the robot)."""
CHI2_95_2DOF = 5.991
"""The 95 % quantile of chi-square with 2 degrees of freedom: the ellipse holds the robot 95 % of the time."""
TRAIL_STEP = 0.01
"""A trail gets a new point once the robot has moved this far, m (a parked robot adds nothing)."""
TRAIL_POINTS = 2000
TRAIL_RATE_HZ = 2.0
"""The whole trail is re-logged at most this often: it is a picture, not a measurement."""

ODOM_COLOR = (60, 140, 255)
LOC_COLOR = (40, 200, 90)
TRUTH_COLOR = (150, 150, 150)
EXTLOC_COLOR = (190, 70, 220)
"""The lab's overhead camera's pose of the robot (``extloc/pose``)."""
MARKER_COLOR = (230, 60, 60)
RAY_COLOR = (250, 200, 40)
SLAM_COLOR = (0, 190, 190)
CAR_COLOR = (255, 120, 40)
"""The virtual car of ``cmd/car`` (``car/state``): its body and trail."""
CAR_WHEEL_COLOR = (40, 40, 40)
REFERENCE_MAP_COLOR = (255, 140, 0)
OBSTACLE_COLOR = (90, 90, 90)
PATH_COLOR = (255, 60, 200)
PENALTY_COLORS = {"tyre_off": (255, 170, 0), "bogged": (200, 40, 40), "ran_stop": (160, 0, 200)}
PENALTY_MARKS = 100
"""Penalty markers kept on the map per lap (a robot wandering off and on for minutes makes many)."""
GRID_FREE_COLOR = (255, 255, 255, 20)
"""A free cell: a faint veil, so the map shows where the grid ends."""
GRID_OCCUPIED_COLOR = (140, 140, 140, 190)
"""An occupied cell: lighter than the obstacles' outlines, which are drawn over it."""
GRID_DRAW_ORDER = -20.0
"""Beneath everything else on the map (Rerun draws lines and points at 30, images at -10)."""
TEXT_LEVELS = {"debug": "DEBUG", "info": "INFO", "warning": "WARN", "error": "ERROR", "critical": "CRITICAL"}


# --------------------------------------------------------------------------- geometry (pure)


def heading(x: float, y: float, theta: float, length: float = ARROW_LENGTH) -> tuple[list[float], list[float]]:
    """Origin and vector of an arrow for a pose."""
    return [x, y], [length * math.cos(theta), length * math.sin(theta)]


def car_outline(x: float, y: float, theta: float, steer: float, wheelbase: float,
                track: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """The virtual car at its rear axle's centre (x, y), heading theta, steered ``steer`` rad (left
    positive): (its body, a closed 5-point outline; its four wheels, each a 2-point segment: rear
    left, rear right, front left, front right), in world coordinates, m.

    The body runs from a fifth of the wheelbase behind the rear axle to a fifth ahead of the front
    one, as wide as the track; each wheel is 0.3 wheelbases long. The front wheels turn as a real
    car's do (Ackermann): each about the one centre the bicycle model turns about, L / tan(steer) to
    the left of the rear axle, so the inner wheel turns more than ``steer`` and the outer less; the
    bicycle model's one wheel, between them, turns by ``steer``."""
    c, s = math.cos(theta), math.sin(theta)

    def world(points: np.ndarray) -> np.ndarray:  # car frame (x forward, y left) -> world
        return np.column_stack([x + c * points[:, 0] - s * points[:, 1], y + s * points[:, 0] + c * points[:, 1]])

    over, half = 0.2 * wheelbase, track / 2
    body = np.array([(-over, -half), (wheelbase + over, -half), (wheelbase + over, half), (-over, half),
                     (-over, -half)])
    tire = 0.15 * wheelbase
    wheels = []
    for ax, side in ((0.0, half), (0.0, -half), (wheelbase, half), (wheelbase, -half)):
        angle = 0.0
        if ax and steer:
            # the wheel's own angle: its axis passes through the turning centre (0, L / tan(steer))
            angle = math.atan2(wheelbase, wheelbase / math.tan(steer) - side)
            angle = math.remainder(angle, math.pi)  # a wheel is a line: left turns positive, right negative
        d = np.array([math.cos(angle), math.sin(angle)]) * tire
        centre = np.array([ax, side])
        wheels.append(world(np.array([centre - d, centre + d])))
    return world(body), wheels


def covariance_ellipse(x: float, y: float, covariance: Sequence[float], points: int = 48) -> np.ndarray:
    """Closed outline of the 95 % ellipse of the (x, y) part of a 3x3 row-major covariance.

    The eigenvectors of the 2x2 block are the ellipse's axes and the square roots of
    its eigenvalues the standard deviations along them.
    """
    if len(covariance) != 9:
        raise ValueError(f"covariance: expected 9 numbers (3x3), got {len(covariance)}")
    block = np.array([[covariance[0], covariance[1]], [covariance[3], covariance[4]]], dtype=float)
    block = (block + block.T) / 2  # rounding can make it a hair asymmetric
    values, vectors = np.linalg.eigh(block)
    radii = np.sqrt(CHI2_95_2DOF * np.clip(values, 0.0, None))  # a negative variance is rounding, not data
    t = np.linspace(0.0, 2 * math.pi, points + 1)
    circle = np.stack([np.cos(t), np.sin(t)])  # 2 x N, the last point closes the loop
    return (vectors @ (radii[:, None] * circle)).T + np.array([x, y])


def landmark_ellipse(x: float, y: float, covariance: Sequence[float], points: int = 24) -> np.ndarray:
    """Closed outline of the 95 % ellipse of a landmark's 2x2 row-major covariance (`LandmarkMap`)."""
    if len(covariance) != 4:
        raise ValueError(f"covariance: expected 4 numbers (2x2), got {len(covariance)}")
    c = covariance
    return covariance_ellipse(x, y, [c[0], c[1], 0.0, c[2], c[3], 0.0, 0.0, 0.0, 0.0], points)


def ray_ends(x: float, y: float, theta: float, landmarks: Sequence[m.Landmark]) -> np.ndarray:
    """Map positions of the landmarks seen from pose (x, y, theta), from their range and bearing."""
    return np.array(
        [[x + lm.range * math.cos(theta + lm.bearing), y + lm.range * math.sin(theta + lm.bearing)]
         for lm in landmarks]
    ).reshape(-1, 2)


def marker_outline(corners: Sequence[float], scale: float = 1.0) -> np.ndarray | None:
    """Closed outline of a detected marker from its 4 corners (x0, y0, ... y3), or None if malformed."""
    if len(corners) != 8:
        return None
    quad = np.asarray(corners, dtype=float).reshape(4, 2) * scale
    return np.vstack([quad, quad[:1]])


def unpack_oled(width: int, height: int, pixels: bytes) -> np.ndarray:
    """A height x width grey image (0 or 255) from 1-bit, row-major, MSB-first pixels."""
    if width <= 0 or height <= 0:
        raise ValueError(f"oled/frame: bad size {width}x{height}")
    if len(pixels) * 8 < width * height:
        raise ValueError(f"oled/frame: {len(pixels)} bytes cannot hold {width}x{height} pixels")
    bits = np.unpackbits(np.frombuffer(pixels, dtype=np.uint8), bitorder="big")
    return (bits[: width * height].reshape(height, width) * 255).astype(np.uint8)


def marker_faces(markers: Sequence[tuple[float, float, float, float]]) -> list[np.ndarray]:
    """Top-down segments of markers (x, y, size, yaw): a marker is a square on a wall, seen edge-on."""
    faces = []
    for x, y, size, yaw in markers:
        # The marker faces along yaw, so its face runs perpendicular to it.
        dx, dy = -math.sin(yaw) * size / 2, math.cos(yaw) * size / 2
        faces.append(np.array([[x - dx, y - dy], [x + dx, y + dy]]))
    return faces


def obstacle_outlines(rects: Sequence[Rectangle]) -> list[np.ndarray]:
    """Closed top-down outlines (5 points) of obstacle footprints (`icefloe.worldmap.Rectangle`)."""
    outlines = []
    for cx, cy, half_length, half_width, yaw in rects:
        c, s = math.cos(yaw), math.sin(yaw)
        corners = [(half_length, half_width), (-half_length, half_width), (-half_length, -half_width),
                   (half_length, -half_width), (half_length, half_width)]
        outlines.append(np.array([(cx + c * u - s * v, cy + s * u + c * v) for u, v in corners]))
    return outlines


def grid_cells(msg: m.OccupancyGrid) -> np.ndarray:
    """The cells of a ``map/grid`` answer as a (height, width) uint8 array, row 0 at y = origin_y;
    ValueError naming the field if the message cannot be a grid, or one larger than
    `icefloe.grid.MAX_CELLS` (a grid is drawn whole: its size is what bounds viz's memory)."""
    if msg.width < 1 or msg.height < 1:
        raise ValueError(f"fields `width` x `height`: {msg.width} x {msg.height} is no grid")
    if msg.width * msg.height > MAX_CELLS or len(msg.cells) > MAX_CELLS:
        raise ValueError(f"fields `width` x `height`: {msg.width} x {msg.height} cells ({len(msg.cells)} bytes in "
                         f"`cells`), more than the {MAX_CELLS} cells a grid may have")
    if len(msg.cells) != msg.width * msg.height:
        raise ValueError(f"field `cells` has {len(msg.cells)} bytes, not `width` x `height` = "
                         f"{msg.width} x {msg.height} = {msg.width * msg.height}")
    if msg.resolution <= 0:
        raise ValueError(f"field `resolution` must be > 0 m, got {msg.resolution}")
    cells = np.frombuffer(msg.cells, dtype=np.uint8).reshape(msg.height, msg.width)
    if cells.max() > OCCUPIED:
        raise ValueError(f"field `cells`: a cell is {FREE} (free) or {OCCUPIED} (occupied), not {int(cells.max())}")
    return cells


class Trail:
    """The recent path of one pose source, thinned by distance."""

    def __init__(self) -> None:
        self.points: deque[tuple[float, float]] = deque(maxlen=TRAIL_POINTS)

    def add(self, x: float, y: float) -> bool:
        """Add a point if the robot moved; True if the trail changed."""
        if self.points:
            px, py = self.points[-1]
            if math.hypot(x - px, y - py) < TRAIL_STEP:
                return False
        self.points.append((x, y))
        return True


# --------------------------------------------------------------------------- Rerun


class RobotLogger:
    """Logs one robot's messages to a Rerun recording under ``/robots/<name>``."""

    def __init__(self, rec: rr.RecordingStream, robot: str, *, capture_width: int = 0,
                 car_size: tuple[float, float] = (0.15, 0.156)) -> None:
        self.rec = rec
        self.robot = robot
        self.root = f"robots/{robot}"
        self.capture_width = capture_width
        """Width of the frames the detector ran on; marker corners are in its pixels (0 = same as the image)."""
        self._image_width = 0
        self._trails = {"odom": Trail(), "loc": Trail(), "truth": Trail(), "extloc": Trail(), "slam": Trail(),
                        "car": Trail()}
        self._trail_rate = {name: Decimator(TRAIL_RATE_HZ) for name in self._trails}
        self._ray_pose: dict[str, tuple[float, float, float]] = {}
        self._nav_state: tuple[str, int, str] | None = None
        self._grid: tuple[object, ...] | None = None
        self._penalties: dict[tuple[int, str], m.JudgeEvent] = {}
        self._judge_lap = 0
        self.car_size = car_size
        """(wheelbase, track) m of the car drawn: the robot's (its ``info``, live), else the config's."""

    def _at(self, stamp: int) -> None:
        self.rec.set_time(TIMELINE, timestamp=np.datetime64(stamp, "ns"))

    def _log(self, path: str, *archetypes: rr.AsComponents, static: bool = False) -> None:
        self.rec.log(f"{self.root}/{path}", *archetypes, static=static)

    def setup(self) -> None:
        """Static data: the map's y flip, series names and colours, so plots read well from the first point."""
        self._log("map", rr.Transform3D(scale=MAP_FLIP), static=True)
        for side in ("left", "right"):
            self._log(f"wheels/{side}/target", rr.SeriesLines(names=f"{side} target", widths=1.5), static=True)
            self._log(f"wheels/{side}/measured", rr.SeriesLines(names=f"{side} measured", widths=1.5),
                      static=True)
        for quantity in ("voltage", "current"):
            self._log(f"battery/{quantity}/filtered", rr.SeriesLines(names="filtered"), static=True)
            self._log(f"battery/{quantity}/raw", rr.SeriesPoints(names="raw", marker_sizes=1.5), static=True)

    # ------------------------------------------------------------------ map

    def landmark_map(self, markers: Sequence[tuple[int, float, float, float, float]]) -> None:
        """The world file's markers (id, x, y, size, yaw), logged once as static data."""
        if not markers:
            return
        self._log("map/landmarks",
                  rr.Points2D([(x, y) for _, x, y, _, _ in markers], labels=[str(i) for i, *_ in markers],
                              colors=MARKER_COLOR, radii=0.02, show_labels=True),
                  static=True)
        faces = marker_faces([(x, y, size, yaw) for _, x, y, size, yaw in markers])
        self._log("map/landmarks/faces", rr.LineStrips2D(faces, colors=MARKER_COLOR, radii=0.01), static=True)

    def obstacles(self, rects: Sequence[Rectangle]) -> None:
        """The world file's obstacles (footprints from `Wall.rectangle`, `Box.rectangle`), static."""
        if rects:
            self._log("map/obstacles", rr.LineStrips2D(obstacle_outlines(rects), colors=OBSTACLE_COLOR, radii=0.008),
                      static=True)

    def grid(self, msg: m.OccupancyGrid) -> bool:
        """The occupancy grid the grid service answers (``map/grid``): drawn when it differs from
        the one drawn last (viz asks again now and then; the grid is large and seldom changes).
        True if it was drawn; ValueError (the caller drops it with one line) if it cannot be a
        grid (`grid_cells`)."""
        cells = grid_cells(msg)
        return self.occupancy(cells, msg.resolution, msg.origin_x, msg.origin_y,
                       (msg.world, msg.inflation, msg.cells))

    def world_grid(self, grid: Grid) -> bool:
        """A grid made here (`icefloe.grid`), e.g. of the world file when a recording is played."""
        return self.occupancy(grid.cells, grid.resolution, grid.origin_x, grid.origin_y,
                       (grid.world, grid.inflation, grid.cells.tobytes()))

    def occupancy(self, cells: np.ndarray, resolution: float, origin_x: float, origin_y: float,
                  what: tuple[object, ...] = ()) -> bool:
        """Cells (rows, cols; row 0 at y = ``origin_y``; 0 free, 1 occupied) as one image on the map,
        static (it stands for the whole run, like the obstacles), again only when it changed.

        Pixel (col, row) of an image covers [col, col + 1) x [row, row + 1) of its space; a
        transform scales that by ``resolution`` and moves it to the origin, so the pixel lands on
        the cell's square in the world (and, under the map's y flip, row 0 at the bottom)."""
        key = (resolution, origin_x, origin_y, cells.shape, *what)
        if key == self._grid:
            return False
        self._grid = key
        self._log("map/grid",
                  rr.AnnotationContext([(FREE, "free", GRID_FREE_COLOR), (OCCUPIED, "occupied", GRID_OCCUPIED_COLOR)]),
                  rr.Transform3D(translation=[origin_x, origin_y, 0.0], scale=[resolution, resolution, 1.0]),
                  rr.SegmentationImage(cells, draw_order=GRID_DRAW_ORDER),
                  static=True)
        return True

    def path(self, msg: m.NavPath) -> None:
        """The path the follower is driving (``nav/path``); an empty one clears it. The schema has
        already refused a path that is too long or not finite, so this is bounded."""
        self._at(msg.stamp or time.time_ns())  # a student's path may carry no stamp
        strips = [[(p.x, p.y) for p in msg.points]] if msg.points else []
        self._log("map/path", rr.LineStrips2D(strips, colors=PATH_COLOR, radii=0.006))

    def nav_status(self, msg: m.FollowStatus) -> None:
        """The follower's state as a log line, when it changes (it is published a few times a second)."""
        state = (msg.state, msg.seq, msg.reason)
        if state == self._nav_state:
            return
        self._nav_state = state
        self._at(msg.stamp)
        why = f": {msg.reason}" if msg.reason else ""
        self._log("log/nav", rr.TextLog(f"{msg.state} path {msg.seq} ({msg.points} points){why}",
                                           level="WARN" if msg.state == "stopped" else "INFO"))

    def judge(self, msg: m.JudgeState) -> None:
        """The lap judge's lap in progress: time and penalty seconds as scalars, the lap in words,
        each new penalty as a marker where it happened (labelled) and a log line."""
        self._at(msg.stamp)
        new_lap = msg.lap != self._judge_lap
        if new_lap:  # its penalties start afresh
            self._judge_lap = msg.lap
            self._penalties.clear()
        fresh = [e for e in msg.events
                 if e.penalty > 0 and e.lap == msg.lap and (e.stamp, e.kind) not in self._penalties]
        for event in fresh:
            if len(self._penalties) < PENALTY_MARKS:
                self._penalties[(event.stamp, event.kind)] = event
            self._log("log/judge", rr.TextLog(f"lap {event.lap}: {event.text} (+{event.penalty:.0f} s)", level="WARN"))
        if fresh or new_lap:
            marks = list(self._penalties.values())
            self._log("map/judge/penalties",
                      rr.Points2D([(e.x, e.y) for e in marks], radii=0.03, show_labels=True,
                                  colors=[PENALTY_COLORS.get(e.kind, MARKER_COLOR) for e in marks],
                                  labels=[f"+{e.penalty:.0f} s {e.kind.replace('_', ' ')}" for e in marks]))
        self._log("judge/lap_time", rr.Scalars(msg.lap_time))
        self._log("judge/penalties", rr.Scalars(msg.penalties))
        best = f", best score {msg.best_score:.2f} s of {msg.laps} laps" if msg.laps else ""
        lap = (f"lap {msg.lap}: {msg.lap_time:.1f} s, penalties {msg.penalties:.0f} s (tyres {msg.tyre_off}, "
               f"bogged {msg.bogged}, stop signs run {msg.ran_stop})" if msg.lap else "waiting at the start line")
        self._log("judge/lap", rr.TextDocument(f"{msg.track}: {lap}{best}"))

    def judge_lap(self, msg: m.JudgeLap) -> None:
        """One lap's result, as a log line."""
        self._at(msg.stamp)
        self._log("log/judge", rr.TextLog(f"lap {msg.lap} of {msg.track}: {msg.time:.2f} s + {msg.penalties:.0f} s "
                                          f"- {msg.reward:.0f} s = {msg.score:.2f} s", level="INFO"))

    def _pose(self, name: str, stamp: int, x: float, y: float, theta: float, color: tuple[int, int, int]) -> None:
        self._at(stamp)
        origin, vector = heading(x, y, theta)
        self._log(f"map/{name}", rr.Arrows2D(origins=[origin], vectors=[vector], colors=color, radii=0.012,
                                             labels=name))
        trail = self._trails.get(name)
        if trail is not None and trail.add(x, y) and self._trail_rate[name].keep(stamp):
            self._log(f"map/{name}/trail", rr.LineStrips2D([list(trail.points)], colors=color, radii=0.004))
        self._ray_pose[name] = (x, y, theta)

    def odom(self, msg: m.Pose) -> None:
        self._pose("odom", msg.stamp, msg.x, msg.y, msg.theta, ODOM_COLOR)

    def truth(self, msg: m.Truth) -> None:
        self._pose("truth", msg.stamp, msg.x, msg.y, msg.theta, TRUTH_COLOR)

    def car(self, msg: m.CarState) -> None:
        """The virtual car at its bicycle-model pose (which starts at 0, 0, 0 where hwbridge started,
        as odometry's does): body and trail in the car's colour, the wheels dark, the front ones at
        the steering angle; labelled with its speed and steering."""
        self._at(msg.stamp)
        wheelbase, track = self.car_size
        body, wheels = car_outline(msg.x, msg.y, msg.theta, msg.steer, wheelbase, track)
        self._log("map/car", rr.LineStrips2D([body, *wheels], colors=[CAR_COLOR] + [CAR_WHEEL_COLOR] * 4,
                                             radii=[0.004] + [0.008] * 4,
                                             labels=[f"car {msg.v:.2f} m/s {math.degrees(msg.steer):+.0f}°"]
                                             + [""] * 4))
        trail = self._trails["car"]
        if trail.add(msg.x, msg.y) and self._trail_rate["car"].keep(msg.stamp):
            self._log("map/car/trail", rr.LineStrips2D([list(trail.points)], colors=CAR_COLOR, radii=0.004))

    def extloc(self, msg: m.ExternalPose) -> None:
        """The overhead camera's pose, next to odometry's and the localizer's, with its uncertainty."""
        self._pose("extloc", msg.stamp, msg.x, msg.y, msg.theta, EXTLOC_COLOR)
        outline = covariance_ellipse(msg.x, msg.y, msg.covariance)  # ValueError: dropped by the caller
        self._log("map/extloc/covariance", rr.LineStrips2D([outline], colors=EXTLOC_COLOR, radii=0.004))

    def loc(self, msg: m.PoseEstimate) -> None:
        self._pose("loc", msg.stamp, msg.x, msg.y, msg.theta, LOC_COLOR)
        outline = covariance_ellipse(msg.x, msg.y, msg.covariance)  # ValueError: dropped by the caller
        self._log("map/loc/covariance", rr.LineStrips2D([outline], colors=LOC_COLOR, radii=0.004))

    def slam(self, msg: m.PoseEstimate) -> None:
        """SLAM's pose, drawn in the map as if SLAM's frame were the world's (it is, when SLAM
        starts where the world's origin is, as the simulated robot does)."""
        self._pose("slam", msg.stamp, msg.x, msg.y, msg.theta, SLAM_COLOR)
        outline = covariance_ellipse(msg.x, msg.y, msg.covariance)
        self._log("map/slam/covariance", rr.LineStrips2D([outline], colors=SLAM_COLOR, radii=0.004))

    def _landmark_map(self, path: str, msg: m.LandmarkMap, color: tuple[int, int, int]) -> None:
        self._at(msg.stamp)
        points = [(p.x, p.y) for p in msg.landmarks]
        self._log(path, rr.Points2D(points, labels=[str(p.id) for p in msg.landmarks], colors=color, radii=0.015,
                                    show_labels=True))
        ellipses = [landmark_ellipse(p.x, p.y, p.covariance) for p in msg.landmarks if len(p.covariance) == 4]
        self._log(f"{path}/covariance", rr.LineStrips2D(ellipses, colors=color, radii=0.003))

    def reference_map(self, msg: m.LandmarkMap) -> None:
        """The map maker's landmarks (``map/landmarks``) with their 95 % ellipses."""
        self._landmark_map("map/reference", msg, REFERENCE_MAP_COLOR)

    def slam_map(self, msg: m.LandmarkMap) -> None:
        """SLAM's landmarks (``slam/map``) with their 95 % ellipses."""
        self._landmark_map("map/slam/landmarks", msg, SLAM_COLOR)

    def landmarks(self, msg: m.Landmarks) -> None:
        """Rays on the map and outlines on the camera image, for the markers seen in one frame."""
        self._at(msg.stamp)
        # Rays start at the best pose we have: the localizer's (map frame), else odometry's.
        pose = self._ray_pose.get("loc") or self._ray_pose.get("odom")
        if pose is not None:
            x, y, _ = pose
            ends = ray_ends(*pose, msg.landmarks)
            # An empty list still gets logged: it clears the rays of the previous frame.
            self._log("map/rays", rr.LineStrips2D([[(x, y), tuple(end)] for end in ends], colors=RAY_COLOR,
                                                  radii=0.003, labels=[str(lm.id) for lm in msg.landmarks]))
        scale = self._image_width / self.capture_width if self.capture_width and self._image_width else 1.0
        outlines, labels = [], []
        for lm in msg.landmarks:
            outline = marker_outline(lm.corners, scale)
            if outline is not None:
                outlines.append(outline)
                labels.append(str(lm.id))
        self._log("camera/image/markers",
                  rr.LineStrips2D(outlines, labels=labels, colors=RAY_COLOR, radii=1.0, show_labels=True))

    # ------------------------------------------------------------------ camera and screen

    def image(self, msg: m.Image) -> None:
        self._at(msg.stamp)
        self._image_width = msg.width
        # The JPEG goes to the viewer as it is: decoding it here would only cost the laptop CPU.
        self._log("camera/image", rr.EncodedImage(contents=msg.data, media_type="image/jpeg"))

    def oled(self, msg: m.OledFrame, received_ns: int | None = None) -> None:
        pixels = unpack_oled(msg.width, msg.height, msg.pixels)  # ValueError: dropped by the caller
        self._at(received_ns if received_ns is not None else time.time_ns())
        self._log("oled", rr.Image(pixels, color_model="L"))

    # ------------------------------------------------------------------ time series

    def wheels(self, msg: m.Wheels) -> None:
        self._at(msg.stamp)
        self._log("wheels/left/target", rr.Scalars(msg.target_left))
        self._log("wheels/left/measured", rr.Scalars(msg.speed_left))
        self._log("wheels/right/target", rr.Scalars(msg.target_right))
        self._log("wheels/right/measured", rr.Scalars(msg.speed_right))

    def battery(self, msg: m.Battery) -> None:
        self._at(msg.stamp)
        self._log("battery/voltage/filtered", rr.Scalars(msg.voltage))
        self._log("battery/current/filtered", rr.Scalars(msg.current))

    def battery_raw(self, msg: m.BatteryReading) -> None:
        self._at(msg.stamp)
        self._log("battery/voltage/raw", rr.Scalars(msg.voltage))
        self._log("battery/current/raw", rr.Scalars(msg.current))

    def loop(self, msg: m.LoopStats) -> None:
        self._at(msg.stamp)
        for name, seconds in (("p50", msg.latency_p50), ("p99", msg.latency_p99),
                              ("p999", msg.latency_p999), ("max", msg.latency_max)):
            self._log(f"loop/latency_ms/{name}", rr.Scalars(seconds * 1e3))
        self._log("loop/errors/overruns", rr.Scalars(msg.overruns))
        self._log("loop/errors/link_errors", rr.Scalars(msg.link_errors))

    def log(self, msg: m.Log) -> None:
        self._at(msg.stamp)
        self._log("log", rr.TextLog(f"[{msg.service}] {msg.text}", level=TEXT_LEVELS.get(msg.level, "INFO")))
