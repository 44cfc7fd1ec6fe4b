"""The Robotics Toolbox for Python (P. Corke, ``pip install "icefloe[rtb]"``) on icefloe's data.

The toolbox's `EKF` is dead reckoning, map-based localization, map making or SLAM depending on
what it is given; each `EKF.step()` asks the vehicle for one odometry increment
(``robot.step()`` -> ``(dd, dth)``) and the sensor for one landmark observation
(``sensor.reading()`` -> ``(array([range, bearing]), id)``, or ``(None, None)``). These adapters
answer those calls with a robot's messages instead of the toolbox's simulation:

* `Feed`: the robot's ``odom/pose``, ``camera/landmarks`` (and, for map making, a known pose:
  ``sim/truth`` or ``extloc/pose``) put in time order and cut into *ticks*: one sighting each,
  with the odometry since the tick before. Fill it from a recording, or live from a
  subscription; it holds back the newest ``holdback`` s so a late camera frame still finds its place.
* `Vehicle`: the toolbox's `Unicycle` whose ``step()`` returns the next tick's odometry
  (its ``x`` is the known pose when the feed has one, else dead reckoning).
* `Sensor`: the toolbox's `RangeBearingSensor` whose ``reading()`` returns the tick's sighting.
* `landmark_map`: a world's markers as the toolbox's `LandmarkMap` (column ``id`` = marker ``id``).
* `occupancy_grid`: icefloe's occupancy grid (icefloe.grid) as the toolbox's `BinaryOccupancyGrid`,
  the map its planners (`DistanceTransformPlanner`, `DstarPlanner`, ...) take.
* `Car` and `drive_car`: the toolbox's `Bicycle` with the robot's virtual car (``[car]``:
  wheelbase, largest angle, steering rate), its control (a constant, a function, or one of the
  toolbox's drivers: `PurePursuit`, `RandomPath`) driving the robot on ``cmd/car`` step by step,
  in real time, while the model predicts where the robot goes (docs/motion-models.md).

The toolbox's Jacobians, noise handling and bookkeeping are its own: only ``step`` and ``reading``
are replaced. Example: examples/rtb_slam.py; docs/slam.md.
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
import math
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import zenoh

try:
    from roboticstoolbox import Bicycle, LandmarkMap, RangeBearingSensor, Unicycle
except ImportError as exc:  # an optional extra: say how to get it, once, when used
    raise ImportError(f"icefloe.rtb needs the Robotics Toolbox: pip install \"icefloe[rtb]\" ({exc})") from None

from .angles import wrap_angle
from .config import RobotConfig
from .errors import MotionStopped
from .schemas import keys
from .schemas import messages as m
from .worldmap import WorldMap

MAX_ID = 999
"""Largest marker id the adapters pass on (ArUco's DICT_4X4_100 has ids 0-99)."""
MAX_PENDING = 100_000
"""Messages a `Feed` holds at most before it drops the oldest (a stalled EKF must not grow memory)."""


@dataclass(frozen=True)
class Tick:
    """One EKF step's worth of data."""

    odo: tuple[float, float]
    """(dd m forward, dth rad) since the tick before: the toolbox's odometry."""
    sighting: tuple[float, float, int] | None
    """(range m, bearing rad, id), or None."""
    pose: tuple[float, float, float] | None
    """The known pose (x, y, theta) at the sighting, if the feed has one."""
    stamp: int


class Feed:
    """The robot's messages in time order, as ticks for `Vehicle` and `Sensor`."""

    def __init__(self, holdback: float = 0.1) -> None:
        """``holdback``: s behind the newest message a tick waits (0: use everything at once)."""
        self.holdback_ns = int(holdback * 1e9)
        self._heap: list[tuple[int, int, object]] = []
        self._order = itertools.count()
        self._newest = 0
        self._odom: tuple[float, float, float] | None = None
        self._odo = [0.0, 0.0]
        self._pose: tuple[float, float, float] | None = None
        self._ready: list[Tick] = []
        self.dropped = 0

    def add(self, msg: m.Pose | m.Truth | m.Landmarks) -> None:
        """An ``odom/pose`` (m.Pose), a known pose (m.Truth, or `known` for an extloc/pose), or a frame."""
        if len(self._heap) >= MAX_PENDING:
            heapq.heappop(self._heap)
            self.dropped += 1
        # frames after poses of the same stamp: the motion up to a frame comes before it
        rank = 1 if isinstance(msg, m.Landmarks) else 0
        heapq.heappush(self._heap, (msg.stamp * 2 + rank, next(self._order), msg))
        self._newest = max(self._newest, msg.stamp)

    def known(self, pose: m.Pose) -> None:
        """An external localizer's pose (``extloc/pose``): the known pose for map making."""
        self.add(m.Truth(stamp=pose.stamp, x=pose.x, y=pose.y, theta=pose.theta))

    def extend(self, msgs: Iterable[m.Pose | m.Truth | m.Landmarks]) -> Feed:
        for msg in msgs:
            self.add(msg)
        return self

    def __len__(self) -> int:
        return len(self._ready) + len(self._heap)

    def next(self) -> Tick:
        """The next tick; with nothing (yet) to say, no motion and no sighting."""
        while not self._ready and self._heap and self._heap[0][0] // 2 <= self._newest - self.holdback_ns:
            self._take(heapq.heappop(self._heap)[2])
        if self._ready:
            return self._ready.pop(0)
        return Tick((0.0, 0.0), None, self._pose, self._newest)

    def _take(self, msg: object) -> None:
        if isinstance(msg, m.Truth):
            self._pose = (msg.x, msg.y, msg.theta)
        elif isinstance(msg, m.Pose):
            new = (msg.x, msg.y, msg.theta)
            if self._odom is not None:
                x0, y0, th0 = self._odom
                dx, dy = new[0] - x0, new[1] - y0
                # forward travel (negative when reversing) and turn: the unicycle's odometry
                self._odo[0] += dx * math.cos(th0) + dy * math.sin(th0)
                self._odo[1] += wrap_angle(new[2] - th0)
            self._odom = new
        elif isinstance(msg, m.Landmarks):
            odo = (self._odo[0], self._odo[1])
            self._odo = [0.0, 0.0]
            if not msg.landmarks:
                self._ready.append(Tick(odo, None, self._pose, msg.stamp))
            for lm in msg.landmarks:
                self._ready.append(Tick(odo, (lm.range, lm.bearing, lm.id), self._pose, msg.stamp))
                odo = (0.0, 0.0)


class Vehicle(Unicycle):
    """The toolbox's unicycle, driven by the robot: ``step()`` returns the robot's odometry."""

    def __init__(self, feed: Feed, covar: np.ndarray | None = None, **kwargs) -> None:
        """``covar``: the odometry's noise, 2 x 2 over (dd m, dth rad), as the toolbox's ``V``.
        ``kwargs`` go to the toolbox's `Unicycle` (``x0``, ``dt``: the toolbox's clock per step)."""
        super().__init__(covar=None, animation=None, **kwargs)
        self.feed = feed
        self.V_icefloe = covar
        self.tick: Tick | None = None

    def step(self, u=None, animate: bool = False, pause: bool = False) -> np.ndarray:  # the toolbox's signature
        self.tick = self.feed.next()
        dd, dth = self.tick.odo
        if self.tick.pose is not None:
            self._x = np.array(self.tick.pose, dtype=float)
        else:
            th = self._x[2]
            self._x = self._x + np.array([dd * math.cos(th), dd * math.sin(th), dth])
        self._x_hist.append(tuple(self._x))
        self._t += self._dt
        return np.array([dd, dth])


class Sensor(RangeBearingSensor):
    """The toolbox's range-bearing sensor, reading the robot's camera: one sighting per call."""

    def __init__(self, robot: Vehicle, map: LandmarkMap | None = None, covar: np.ndarray | None = None,
                 **kwargs) -> None:
        """``map``: the landmarks for map-based localization (`landmark_map`); None for map
        making and SLAM. ``covar``: the sightings' noise, 2 x 2 over (range m, bearing rad)."""
        # The toolbox's EKF predicts every reading from the sensor's map before it knows whether the
        # landmark is new (EKF.step: ``self.sensor.h(x, id)``), so map making and SLAM still need a
        # column per id: placeholders, never used as positions.
        self.known = map is not None
        super().__init__(robot, map if map is not None else LandmarkMap(np.zeros((2, MAX_ID + 1))), covar=covar,
                         plot=False, **kwargs)

    def reading(self) -> tuple[np.ndarray | None, int | None]:
        tick = self.robot.tick
        if tick is None or tick.sighting is None:
            return None, None
        r, b, lm_id = tick.sighting
        if not 0 <= lm_id < self.map.landmarks.shape[1] or not np.all(np.isfinite(self.map[lm_id])):
            return None, None  # a marker not in the map (localization), or an id beyond MAX_ID
        return np.array([r, b]), lm_id


def landmark_map(world: WorldMap) -> LandmarkMap:
    """A world's markers as the toolbox's map: column ``id`` holds marker ``id`` (others NaN)."""
    ids = [mk.id for mk in world.markers]
    cols = np.full((2, max(ids) + 1 if ids else 0), np.nan)
    for mk in world.markers:
        cols[:, mk.id] = (mk.x, mk.y)
    xs, ys = [mk.x for mk in world.markers] or [0.0], [mk.y for mk in world.markers] or [0.0]
    return LandmarkMap(cols, workspace=[min(xs) - 1, max(xs) + 1, min(ys) - 1, max(ys) + 1])


def occupancy_grid(grid):
    """icefloe's `icefloe.grid.Grid` as the toolbox's `BinaryOccupancyGrid` (same cells, origin, cell size)."""
    from roboticstoolbox import BinaryOccupancyGrid

    return BinaryOccupancyGrid(np.asarray(grid.cells, dtype=bool), cellsize=grid.resolution,
                               origin=(grid.origin_x, grid.origin_y))


class Car(Bicycle):
    """The toolbox's `Bicycle` with the robot's virtual car: L = ``car.wheelbase``, ``steer_max`` =
    ``car.max_steer``, ``speed_max`` = ``hwbridge.max_wheel_speed``, and the car's steering rate
    (``car.steer_rate``), which the toolbox's Bicycle lacks: the steering turns towards the angle asked
    for by at most ``steer_rate * dt`` a step, from where it is, as hwbridge turns it (so the model
    predicts what the robot does, not what it was asked). ``u`` is the last step's (v m/s, steer rad),
    what `drive_car` sends. Its control and ``x0``, ``dt`` (s a step) are the toolbox's keywords."""

    def __init__(self, config: RobotConfig, **kwargs) -> None:
        kwargs.setdefault("speed_max", config.hwbridge.max_wheel_speed)
        super().__init__(L=config.car.wheelbase, steer_max=config.car.max_steer, animation=None, **kwargs)
        self.steer_rate = config.car.steer_rate
        self.u = np.zeros(2)
        self._steer = 0.0

    def init(self, *args, **kwargs) -> None:
        super().init(*args, **kwargs)
        self._steer = 0.0
        self.u = np.zeros(2)

    def u_limited(self, u) -> np.ndarray:
        # The toolbox calls this twice a step (eval_control, then deriv with the limited u): the
        # second call finds the steering where the first left it, and changes nothing.
        ulim = super().u_limited(np.asarray(u, dtype=float))
        most = self.steer_rate * self.dt
        ulim[1] = self._steer + float(np.clip(ulim[1] - self._steer, -most, most))
        self._steer = float(ulim[1])
        self.u = ulim
        return ulim


async def drive_car(car: Car, robot, duration: float) -> np.ndarray:
    """Drive ``robot`` (an `icefloe.client.AsyncRobot`) with ``car``'s control for ``duration`` s: each
    ``car.dt`` s from the first one sent (by the wall clock, as hwbridge's steering and deadman run;
    the toolbox's first step is slow) one toolbox step, its (v, steer) sent as ``cmd/car`` and
    integrated by the model; then the robot is stopped (confirmed),
    also when this is cancelled or fails (a control that gives NaN: `ValueError` naming ``v`` or
    ``steer``). A ``cmd/stop`` from another program (a teacher's stop, ``icefloe pub cmd/stop``) ends
    the drive: `MotionStopped`, and nothing more is sent. Returns the model's prediction,
    ``car.x_hist`` (one row (x, y, theta) per step, from ``car``'s ``x0``).

    The drivers steer by the model's pose, as in the toolbox: the robot follows the model's commands
    open loop, and where it ends differs from the prediction by what the model leaves out (wheel
    slip, the wheels' acceleration, a loaded machine)."""
    stopped = threading.Event()
    listener = robot.node.on_samples(robot.node.key(keys.STOP), lambda _sample: stopped.set(),
                                     allowed_origin=zenoh.Locality.REMOTE)
    car.init(animate=False)
    start = 0.0
    try:
        async with robot.car(0.0, 0.0):
            for i in range(round(duration / car.dt)):
                car.step(animate=False)
                if stopped.is_set():
                    raise MotionStopped(f"rtb.drive_car: ended by a cmd/stop from another program after {i} of "
                                        f"{round(duration / car.dt)} steps")
                await robot.drive_car(float(car.u[0]), float(car.u[1]))
                if i == 0:  # the schedule starts with the first step sent, not before the first (slower) one
                    start = time.monotonic()
                await asyncio.sleep(max(0.0, start + (i + 1) * car.dt - time.monotonic()))
    finally:
        listener.undeclare()
    return car.x_hist
