"""The lap judge's rules, as the RVSS workshop's instructions give them, over the simulator's truth.

RVSS "Need 4 Speed", ``instructions/Task.md`` (rvss-australia/RVSS_Need4Speed)::

    Score = Delivery time + penalties - rewards

* **Delivery time**: the time to complete a lap. Here: from the robot's centre crossing the
  start/finish line (``Track.start``, in its driving direction) to crossing it again, after it
  went round (it passed the second, third and fourth quarter of the centerline since).
* **Popped tyre, +1 s**: "if your entire tyre leaves the road surface". A tyre is what the robot
  stands on seen from above: a segment as long as the wheel's diameter, along the heading, at
  half the wheel track to each side of the centre (``geometry.wheel_diameter``, ``geometry.track``).
  Entirely off: none of its `TYRE_POINTS` is on the road. Once per excursion: the same tyre
  costs again only after part of it was back on the road.
* **Bogged, +5 s**: "if your entire robot leaves the road surface": no point of the robot's
  footprint (the disc of ``geometry.radius`` that holds all of it, and both tyres) is on the
  road. Once per excursion. The tyres left first, so a robot that leaves the road entirely has
  paid for them too (+1 s each) before the +5 s: each event happened, and each is counted once.
* **Run a stop sign, +10 s**: "When your robot is within 10cm of the stop sign, it must come to
  a complete stop *before* the stop sign." The robot's centre crossing a sign's stop line (the
  line through ``stop_x, stop_y`` across the road, in the direction the sign stops) costs 10 s
  unless, since it last crossed it, the robot was `stopped` with its front (the footprint disc's
  nearest point to the line) no more than ``stop_zone`` (0.10 m) before the line and not past it.
* **City's Safest Driver, -5 s**: a lap with no penalty.

"Stopped", precisely: the robot's centre stayed within ``stop_tolerance`` (5 mm) and its heading
within `STILL_HEADING` (0.05 rad) of where they were, for ``stop_dwell_s`` (0.5 s) of truth
time. Why: the truth has no noise, so any motion shows; 5 mm in 0.5 s is a mean speed under
1 cm/s, below the slowest the PenguinPi drives (its motors' dead band), so a robot that creeps
is not stopped; a speed sample passing through zero (a robot reversing) lasts one sample, not
half a second; and half a second is what a person judging by eye sees as a complete stop.

Penalties count only while a lap runs (before the first crossing of the start line, nothing
does). This module knows no bus: `Judge.feed` takes one truth sample and returns what happened.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from icefloe.angles import wrap_angle

TYRE_PENALTY = 1.0
"""s: "Popped tyre"."""
BOGGED_PENALTY = 5.0
"""s: "Bogged"."""
STOP_PENALTY = 10.0
"""s: "Run a stop sign"."""
SAFE_REWARD = 5.0
"""s: "City's Safest Driver", a lap without penalty."""

TYRE_POINTS = 5
"""Points along a tyre's contact segment that are tested for road (its ends included)."""
DISC_POINTS = 12
"""Points on each of the footprint disc's two rings (half radius, full radius)."""
STILL_HEADING = 0.05
"""rad: a robot turning on the spot is not stopped."""
PROGRESS_STEP = 0.02
"""m: spacing of the resampled centerline the robot's progress is read from."""
MAX_LAP_EVENTS = 200
"""Events kept per lap (a robot that wanders off and on for minutes makes many)."""


class SignLike(Protocol):
    """What the judge reads of a `icefloe.track.Sign`."""

    @property
    def kind(self) -> str: ...
    @property
    def stop_x(self) -> float: ...
    @property
    def stop_y(self) -> float: ...
    @property
    def yaw(self) -> float: ...


class TrackLike(Protocol):
    """What the judge reads of a `icefloe.track.Track` (world frame, m)."""

    @property
    def name(self) -> str: ...
    @property
    def road_width(self) -> float: ...
    @property
    def signs(self) -> Sequence[SignLike]: ...
    @property
    def start(self) -> tuple[float, float, float]: ...
    def on_road(self, x: float, y: float) -> bool: ...
    def centerline(self) -> np.ndarray: ...
    def lap_length(self) -> float: ...


@dataclass(frozen=True)
class Rules:
    """The robot's shape and the judge's thresholds (``[geometry]`` and ``[judge]`` of the config)."""

    wheel_track: float = 0.156
    """m between the tyres' centres."""
    wheel_diameter: float = 0.065
    """m: a tyre's contact segment is this long."""
    radius: float = 0.1
    """m: the disc around the centre that holds all of the robot."""
    stop_zone: float = 0.10
    """m: how far before the stop line the robot's front may be when it stops."""
    stop_dwell_s: float = 0.5
    """s the robot must stand still to be stopped."""
    stop_tolerance: float = 0.005
    """m the centre may move while standing still."""


@dataclass(frozen=True)
class Event:
    """One thing the judge saw (`icefloe.schemas.messages.JudgeEvent` on the bus)."""

    t: float
    """s, the truth's clock."""
    kind: str
    """lap_start, lap_end, tyre_off, bogged, ran_stop, stopped."""
    lap: int
    penalty: float
    x: float
    y: float
    text: str


@dataclass
class Lap:
    """A lap in progress or done."""

    number: int
    start: float
    """s, the truth's clock, when the robot crossed the start line."""
    end: float | None = None
    events: list[Event] = field(default_factory=list)
    tyre_off: int = 0
    bogged: int = 0
    ran_stop: int = 0

    @property
    def penalties(self) -> float:
        return self.tyre_off * TYRE_PENALTY + self.bogged * BOGGED_PENALTY + self.ran_stop * STOP_PENALTY

    @property
    def reward(self) -> float:
        return SAFE_REWARD if self.penalties == 0 else 0.0

    def time(self, now: float) -> float:
        """Delivery time, s: to its end, or to ``now`` while it runs."""
        return (self.end if self.end is not None else now) - self.start

    def score(self, now: float) -> float:
        return self.time(now) + self.penalties - self.reward


def _tyre_offsets(rules: Rules) -> dict[str, np.ndarray]:
    """Each tyre's test points in the robot's frame (x forward, y left), m."""
    along = np.linspace(-rules.wheel_diameter / 2, rules.wheel_diameter / 2, TYRE_POINTS)
    half = rules.wheel_track / 2
    return {"left": np.column_stack([along, np.full_like(along, half)]),
            "right": np.column_stack([along, np.full_like(along, -half)])}


def _disc_offsets(rules: Rules) -> np.ndarray:
    angles = np.linspace(0, 2 * math.pi, DISC_POINTS, endpoint=False)
    rings = [np.column_stack([r * np.cos(angles), r * np.sin(angles)]) for r in (rules.radius / 2, rules.radius)]
    return np.vstack([np.zeros((1, 2)), *rings])


def _resample(line: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` m along a polyline and their arc lengths from its first point."""
    seg = np.diff(line, axis=0)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    s = np.arange(0.0, cum[-1], step) if cum[-1] > 0 else np.zeros(1)
    return np.column_stack([np.interp(s, cum, line[:, 0]), np.interp(s, cum, line[:, 1])]), s


class Judge:
    """Scores laps from a stream of truth samples; `feed` one at a time, in time order."""

    def __init__(self, track: TrackLike, rules: Rules = Rules()) -> None:
        self.track = track
        self.rules = rules
        self.laps: list[Lap] = []
        """Laps started, the one in progress last."""
        self.now = 0.0
        self._prev: tuple[float, float, float, float] | None = None
        self._tyres = _tyre_offsets(rules)
        self._disc = _disc_offsets(rules)
        self._tyre_out = {"left": False, "right": False}
        self._bogged = False
        self._still = (0.0, 0.0, 0.0, 0.0)  # t, x, y, theta where the robot last stood still from
        self._stopped_ok = [False] * len(track.signs)
        sx, sy, syaw = track.start
        self._start = (sx, sy, math.cos(syaw), math.sin(syaw))
        self._half_width = track.road_width / 2 + rules.radius
        line = np.asarray(track.centerline(), dtype=float)
        self._line, self._arc = _resample(line, PROGRESS_STEP)
        self._length = max(float(track.lap_length()), PROGRESS_STEP)
        self._quarters: set[int] = set()

    # ----------------------------------------------------------------- state

    @property
    def lap(self) -> Lap | None:
        """The lap in progress, or None before the first start."""
        return self.laps[-1] if self.laps and self.laps[-1].end is None else None

    @property
    def finished(self) -> list[Lap]:
        return [lap for lap in self.laps if lap.end is not None]

    # ----------------------------------------------------------------- one sample

    def feed(self, t: float, x: float, y: float, theta: float) -> list[Event]:
        """One truth sample (s, m, m, rad); the events it caused, in order."""
        t, x, y, theta = float(t), float(x), float(y), float(theta)  # numpy's floats do not go on the bus
        events: list[Event] = []
        prev = self._prev
        self._prev = (t, x, y, theta)
        self.now = t
        if prev is None:
            self._still = (t, x, y, theta)
            return events
        self._progress(x, y)
        self._start_line(prev, t, x, y, events)
        self._road(t, x, y, theta, events)
        self._stop_signs(prev, t, x, y, theta, events)
        return events

    def _event(self, events: list[Event], t: float, kind: str, penalty: float, x: float, y: float,
               text: str) -> None:
        lap = self.lap
        counted = penalty if lap is not None else 0.0
        event = Event(t=t, kind=kind, lap=lap.number if lap else 0, penalty=counted, x=x, y=y, text=text)
        if lap is not None:
            if kind in ("tyre_off", "bogged", "ran_stop"):
                setattr(lap, kind, getattr(lap, kind) + 1)
            if len(lap.events) < MAX_LAP_EVENTS:
                lap.events.append(event)
        events.append(event)

    # ----------------------------------------------------------------- laps

    def _progress(self, x: float, y: float) -> None:
        """Mark the quarter of the lap the robot is in (its nearest centerline point's)."""
        d2 = (self._line[:, 0] - x) ** 2 + (self._line[:, 1] - y) ** 2
        s = float(self._arc[int(np.argmin(d2))])
        self._quarters.add(min(3, int(4 * s / self._length)))

    def _start_line(self, prev: tuple[float, float, float, float], t: float, x: float, y: float,
                    events: list[Event]) -> None:
        sx, sy, fx, fy = self._start
        before = (prev[1] - sx) * fx + (prev[2] - sy) * fy
        after = (x - sx) * fx + (y - sy) * fy
        lateral = abs(-(x - sx) * fy + (y - sy) * fx)
        if not (before <= 0.0 < after and lateral <= self._half_width):
            return
        crossed = prev[0] + (t - prev[0]) * (-before) / (after - before)
        lap = self.lap
        if lap is not None:
            if not {1, 2, 3} <= self._quarters:
                return  # back and forth over the line: not a lap
            self._event(events, crossed, "lap_end", 0.0, x, y,
                        f"lap {lap.number}: {lap.time(crossed):.2f} s + {lap.penalties:.0f} s penalties"
                        f" - {lap.reward:.0f} s reward = {lap.score(crossed):.2f} s")
            lap.end = crossed
        self.laps.append(Lap(number=len(self.laps) + 1, start=crossed))
        self._quarters = {0}
        self._event(events, crossed, "lap_start", 0.0, x, y, f"lap {len(self.laps)} started")

    # ----------------------------------------------------------------- road

    def _world(self, offsets: np.ndarray, x: float, y: float, theta: float) -> list[tuple[float, float]]:
        c, s = math.cos(theta), math.sin(theta)
        return [(x + c * px - s * py, y + s * px + c * py) for px, py in offsets]

    def _any_on(self, points: list[tuple[float, float]]) -> bool:
        return any(self.track.on_road(px, py) for px, py in points)

    def _road(self, t: float, x: float, y: float, theta: float, events: list[Event]) -> None:
        tyres_on = {side: self._any_on(self._world(pts, x, y, theta)) for side, pts in self._tyres.items()}
        for side, on in tyres_on.items():
            if not on and not self._tyre_out[side]:
                self._event(events, t, "tyre_off", TYRE_PENALTY, x, y, f"{side} tyre off the road")
            self._tyre_out[side] = not on
        robot_on = any(tyres_on.values()) or self._any_on(self._world(self._disc, x, y, theta))
        if not robot_on and not self._bogged:
            self._event(events, t, "bogged", BOGGED_PENALTY, x, y, "the whole robot off the road")
        self._bogged = not robot_on

    # ----------------------------------------------------------------- stop signs

    def stopped(self) -> bool:
        """Has the robot stood still for ``stop_dwell_s`` up to the newest sample?"""
        return self._prev is not None and self._prev[0] - self._still[0] >= self.rules.stop_dwell_s

    def _stop_signs(self, prev: tuple[float, float, float, float], t: float, x: float, y: float,
                    theta: float, events: list[Event]) -> None:
        _, x0, y0, th0 = self._still
        if math.hypot(x - x0, y - y0) > self.rules.stop_tolerance or abs(wrap_angle(theta - th0)) > STILL_HEADING:
            self._still = (t, x, y, theta)
        stopped = self.stopped()
        for i, sign in enumerate(self.track.signs):
            if sign.kind != "stop":
                continue
            # The sign's face looks at the traffic it stops: "before the line" is along its yaw.
            nx, ny = math.cos(sign.yaw), math.sin(sign.yaw)
            ahead = (x - sign.stop_x) * nx + (y - sign.stop_y) * ny
            lateral = abs(-(x - sign.stop_x) * ny + (y - sign.stop_y) * nx)
            if lateral > self._half_width:
                continue
            front = ahead - self.rules.radius
            if stopped and 0.0 <= front <= self.rules.stop_zone and not self._stopped_ok[i]:
                self._stopped_ok[i] = True
                self._event(events, t, "stopped", 0.0, x, y,
                            f"stopped {100 * front:.0f} cm before stop sign {i}'s line")
            was = (prev[1] - sign.stop_x) * nx + (prev[2] - sign.stop_y) * ny
            if was > 0.0 >= ahead:  # the centre crossed the line the way the sign stops
                if not self._stopped_ok[i]:
                    self._event(events, t, "ran_stop", STOP_PENALTY, x, y, f"ran stop sign {i} without stopping")
                self._stopped_ok[i] = False
