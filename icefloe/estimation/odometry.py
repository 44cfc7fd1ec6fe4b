"""Differential-drive dead reckoning from encoder counts: pure logic, no bus.

The odometry service runs it on ``hw/wheels``; the square-run harness (`simrun`) on the
simulated world's counts.

Conventions (the same as the whole bus, see ``schemas/messages.py``):

* Odometry frame: x forward at the start, y to the left, z up; metres.
* ``theta`` counter-clockwise positive, wrapped to (-pi, pi]; radians.
* Encoder counts increase when the wheel drives the robot forward.

The motion model (docs/odometry.md has the derivation). One encoder sample
gives the count differences dN_L, dN_R since the last sample. With
k = pi * D / N_rev metres per count (D wheel diameter, N_rev counts per turn)
and b the track::

    d_L = k dN_L,   d_R = k dN_R               (wheel rim travel, m)
    ds  = (d_R + d_L) / 2                      (travel of the axle centre, m)
    dth = (d_R - d_L) / b                      (heading change, rad, CCW +)

If both wheels turned at constant speed during the sample (the only
assumption we can make from two counts), the centre moved along a circular
arc, and the exact pose update is (Thrun, Burgard, Fox, *Probabilistic
Robotics*, 2005, eq. 5.9, rewritten with ds = v dt, dth = w dt)::

    x'  = x + ds * sinc(dth/2) * cos(theta + dth/2)
    y'  = y + ds * sinc(dth/2) * sin(theta + dth/2)
    th' = wrap(theta + dth)            sinc(u) = sin(u)/u, sinc(0) = 1

The chord of the arc has length ds*sinc(dth/2) and points along the mean
heading. This form has no division by w, so a straight line (dth = 0) is not
a special case. The old PenguinPi thread used the chord direction but the
arc length, a first-order step that is off by the factor sinc(dth/2).
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from typing import ClassVar

from ..angles import wrap_angle
from ..config import RobotConfig
from ..logs import LimitedLog
from ..schemas import messages as m

INT16_MIN, INT16_MAX = -32768, 32767
"""Range of a raw 16-bit encoder counter (PenguinPi and icoBoard both count in int16)."""


def sinc(u: float) -> float:
    """sin(u)/u, with its limit 1 at u = 0 (Taylor series near 0 to keep full precision)."""
    if abs(u) < 1e-4:
        return 1.0 - u * u / 6.0
    return math.sin(u) / u


def count_delta(new: int, old: int) -> int:
    """Counts moved from ``old`` to ``new``, correct across a raw 16-bit wrap.

    hwbridge publishes unwrapped counts, so normally this is ``new - old``.
    When both values lie in the int16 range we also accept raw 16-bit counts:
    the difference taken modulo 2^16 into [-32768, 32767] is the short way
    round, in both directions (32767 -> -32768 is +1, -32768 -> 32767 is -1).
    An unwrapped count can only look like a wrap after a jump of more than
    32768 counts (over 27 m of rim travel), which the plausibility check
    rejects anyway.
    """
    d = new - old
    if INT16_MIN <= new <= INT16_MAX and INT16_MIN <= old <= INT16_MAX:
        d = (d - INT16_MIN) % 65536 + INT16_MIN
    return d


@dataclass(frozen=True)
class Geometry:
    """What the integration needs of the robot (``config.geometry``)."""

    wheel_diameter: float
    """m."""
    track: float
    """Distance between the wheels' contact points, m."""
    ticks_per_rev: int
    """Encoder counts per wheel turn."""

    @property
    def metres_per_tick(self) -> float:
        """Rim travel per encoder count, m."""
        return math.pi * self.wheel_diameter / self.ticks_per_rev


@dataclass(frozen=True)
class Limits:
    """What counts as a glitch rather than motion (``config.odometry``)."""

    max_wheel_speed: float = 1.0
    """m/s."""
    jump_margin: float = 0.005
    """m per sample, on top of max_wheel_speed * dt."""
    gap_s: float = 0.25
    """A longer silence is reported (its motion is still integrated), s."""
    speed_window_s: float = 0.1
    """v and w are averaged over this long, s."""


class Event(Enum):
    """What happened to one encoder sample. Everything but MOVED and GAP leaves the pose unchanged."""

    FIRST = "first sample: reference taken"
    MOVED = "integrated"
    GAP = "integrated across a gap"
    BACKWARDS = "timestamp went backwards: not integrated, new reference taken"
    JUMP = "count jump too large to be motion (encoder reset or bridge restart?): not integrated, new reference taken"
    BAD = "not a finite integer sample: ignored"


@dataclass(frozen=True)
class Step:
    """The outcome of one sample: the event and, for the log, what was seen."""

    event: Event
    d_left: int = 0
    """Counts, left wheel."""
    d_right: int = 0
    dt: float = 0.0
    """s since the previous sample."""

    def describe(self) -> str:
        return f"{self.event.value} (dL={self.d_left} dR={self.d_right} counts, dt={self.dt:.4f} s)"


class Odometry:
    """Integrates encoder samples into a pose. Feed it every ``hw/wheels`` sample with `update`."""

    def __init__(self, geometry: Geometry, limits: Limits | None = None) -> None:
        self.geometry = geometry
        self.limits = limits or Limits()
        self.x = 0.0
        """m."""
        self.y = 0.0
        """m."""
        self.theta = 0.0
        """rad, in (-pi, pi]."""
        self.stamp = 0
        """ns, the last sample integrated or taken as reference (0 = none yet)."""
        self._ref: tuple[int, int, int] | None = None  # (stamp ns, left, right) of the previous sample
        # Path length and unwrapped heading, for the v and w window: (stamp ns, s m, heading rad).
        self._path_s = 0.0
        self._heading = 0.0
        self._window: deque[tuple[int, float, float]] = deque()

    # ------------------------------------------------------------------ input

    def update(self, stamp: int, left: int, right: int) -> Step:
        """Take one encoder sample (stamp in ns, cumulative counts); integrate it if it is motion."""
        if not all(type(v) is int for v in (stamp, left, right)):  # bool and float are refused too
            return Step(Event.BAD)
        if self._ref is None:
            self._rebase(stamp, left, right)
            return Step(Event.FIRST)
        t0, l0, r0 = self._ref
        d_left, d_right = count_delta(left, l0), count_delta(right, r0)
        dt = (stamp - t0) * 1e-9
        if dt < 0:
            self._rebase(stamp, left, right)
            return Step(Event.BACKWARDS, d_left, d_right, dt)
        k = self.geometry.metres_per_tick
        allowed = self.limits.max_wheel_speed * dt + self.limits.jump_margin
        if max(abs(d_left), abs(d_right)) * k > allowed:
            self._rebase(stamp, left, right)
            return Step(Event.JUMP, d_left, d_right, dt)
        self._ref = (stamp, left, right)
        self.stamp = stamp
        self._integrate(k * d_left, k * d_right)
        self._remember(stamp)
        return Step(Event.GAP if dt > self.limits.gap_s else Event.MOVED, d_left, d_right, dt)

    def reset(self, x: float = 0.0, y: float = 0.0, theta: float = 0.0) -> None:
        """Set the pose (m, m, rad). The encoder reference is kept: motion goes on from here."""
        if not all(math.isfinite(v) for v in (x, y, theta)):
            raise ValueError(f"reset pose must be finite, got x={x} y={y} theta={theta}")
        self.x, self.y, self.theta = float(x), float(y), wrap_angle(theta)

    # ------------------------------------------------------------------ output

    def speeds(self) -> tuple[float, float]:
        """(v m/s, w rad/s): the mean over the last ``speed_window_s`` of samples (0, 0 if unknown)."""
        if len(self._window) < 2:
            return 0.0, 0.0
        (t0, s0, h0), (t1, s1, h1) = self._window[0], self._window[-1]
        dt = (t1 - t0) * 1e-9
        return ((s1 - s0) / dt, (h1 - h0) / dt) if dt > 0 else (0.0, 0.0)

    # ------------------------------------------------------------------ internals

    def _integrate(self, d_left: float, d_right: float) -> None:
        """Exact arc step for rim travels d_left, d_right (m); see the module docstring."""
        ds = 0.5 * (d_right + d_left)
        dth = (d_right - d_left) / self.geometry.track
        chord = ds * sinc(0.5 * dth)
        mid = self.theta + 0.5 * dth
        self.x += chord * math.cos(mid)
        self.y += chord * math.sin(mid)
        self.theta = wrap_angle(self.theta + dth)
        self._path_s += ds
        self._heading += dth

    def _rebase(self, stamp: int, left: int, right: int) -> None:
        """Take this sample as the new reference without moving; v and w restart."""
        self._ref = (stamp, left, right)
        self.stamp = stamp
        self._window.clear()
        self._remember(stamp)

    def _remember(self, stamp: int) -> None:
        self._window.append((stamp, self._path_s, self._heading))
        horizon = stamp - int(self.limits.speed_window_s * 1e9)
        # Keep one sample at or before the horizon so the window spans the full length.
        while len(self._window) > 2 and self._window[1][0] <= horizon:
            self._window.popleft()


def make_odometry(config: RobotConfig) -> Odometry:
    """The pure integrator configured from the robot config."""
    g, o = config.geometry, config.odometry
    return Odometry(
        Geometry(g.wheel_diameter, g.track, g.ticks_per_rev),
        Limits(o.max_wheel_speed, o.jump_margin, o.gap_s, o.speed_window_s),
    )


def pose_message(odo: Odometry) -> m.Pose:
    v, w = odo.speeds()
    return m.Pose(stamp=odo.stamp, x=odo.x, y=odo.y, theta=odo.theta, v=v, w=w)


class EventLog:
    """Logs each unusual sample with what was seen: up to `burst` lines per kind per second.

    A storm (say, a board that keeps resetting) becomes a few lines plus a
    count instead of a thousand lines a second (`LimitedLog`).
    """

    INTERESTING: ClassVar[dict[Event, int]] = {Event.GAP: logging.INFO, Event.BACKWARDS: logging.WARNING,
                                               Event.JUMP: logging.WARNING, Event.BAD: logging.WARNING}

    def __init__(self, log: logging.Logger, clock: Callable[[], float] = time.monotonic, burst: int = 5) -> None:
        self._limited = LimitedLog(log, burst=burst, limit=2 * burst, clock=clock)
        self.counts: dict[Event, int] = {e: 0 for e in Event}
        """Samples seen per kind, since start."""

    def note(self, step: Step) -> None:
        self.counts[step.event] += 1
        level = self.INTERESTING.get(step.event)
        if level is not None:
            self._limited.write(level, f"hw/wheels {step.event.name.lower()}", "hw/wheels: %s", step.describe())
