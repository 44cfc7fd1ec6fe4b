"""The pure logic of hwbridge: units, clamping, ramps, the deadman, PI control, timed motion.

Nothing here reads a clock, touches the bus or the board: every function takes
the time it needs as an argument, so tests drive it exactly. The real-time
cycle (`rt.py`) and the bus side (`__main__.py`) call into these classes.

Units: speeds are wheel rim speeds in m/s, times in seconds (float) unless a
name ends in ``_ns`` (integer nanoseconds), encoder positions in counts.
"""

from __future__ import annotations

import math
from collections.abc import MutableSequence

from icefloe.config import Geometry
from icefloe.motion.diffdrive import limit_wheels, twist_to_wheels  # noqa: F401 - they live in icefloe.motion

# --------------------------------------------------------------------------- units


def metres_per_tick(geometry: Geometry) -> float:
    """Rim distance of one encoder count, m (π·0.065/384 ≈ 0.532 mm on the PenguinPi)."""
    return math.pi * geometry.wheel_diameter / geometry.ticks_per_rev


PENGUINPI_DEMAND_LIMIT = 100
"""The firmware's PI controller saturates at ±100, so a larger demand only winds it up."""

PENGUINPI_COUNTS_PER_S_PER_DEMAND = 10.0
"""Firmware steady state: demand d runs the wheel at 10·d counts/s (target = d/5 counts per 20 ms)."""


def speed_to_demand(speed: float, geometry: Geometry) -> int:
    """Rim speed (m/s) -> PenguinPi velocity demand, rounded and clamped to ±100.

    One demand unit is 10 counts/s = 10 · metres_per_tick ≈ 5.32 mm/s.
    """
    per_unit = PENGUINPI_COUNTS_PER_S_PER_DEMAND * metres_per_tick(geometry)
    demand = round(speed / per_unit)
    return max(-PENGUINPI_DEMAND_LIMIT, min(PENGUINPI_DEMAND_LIMIT, demand))


def demand_to_speed(demand: int, geometry: Geometry) -> float:
    """PenguinPi velocity demand -> nominal steady rim speed, m/s."""
    return demand * PENGUINPI_COUNTS_PER_S_PER_DEMAND * metres_per_tick(geometry)


PENGUINPI_CONTROL_PERIOD_NS = 20_000_000
"""The firmware runs its wheel controller every 20 ms."""


class DemandDither:
    """Speed (m/s) -> PenguinPi demand whose *average* speed is the one asked for.

    The firmware turns a demand d into a target of trunc(d / 5) counts per 20 ms,
    so on its own it can only run at multiples of 50 counts/s (~26.6 mm/s):
    0.15 m/s would become 0.133 m/s. Error diffusion fixes the average: each
    20 ms we send 5·q, with q the whole counts per 20 ms, and carry what q left
    out into the next period (first-order sigma-delta). Between updates the
    demand is held, so the firmware sees about one value per control period.
    """

    def __init__(self, geometry: Geometry) -> None:
        self.counts_per_metre = 1.0 / metres_per_tick(geometry)
        self.carry = 0.0
        """Counts per 20 ms not yet delivered."""
        self.demand = 0
        self._next_ns = 0

    def step(self, speed: float, now_ns: int) -> int:
        """The demand to send at ``now_ns`` for a wheel speed of ``speed`` m/s."""
        if speed == 0.0:
            self.carry, self.demand, self._next_ns = 0.0, 0, 0
            return 0
        if now_ns < self._next_ns:
            return self.demand
        self._next_ns = now_ns + PENGUINPI_CONTROL_PERIOD_NS
        want = speed * self.counts_per_metre * PENGUINPI_CONTROL_PERIOD_NS * 1e-9 + self.carry
        limit = PENGUINPI_DEMAND_LIMIT // 5
        q = max(-limit, min(limit, round(want)))
        # Keep at most one step of carry, so a saturated wheel does not store up a debt.
        self.carry = clamp(want - q, -1.0, 1.0)
        self.demand = 5 * q
        return self.demand


def clamp(value: float, low: float, high: float) -> float:
    return low if value < low else high if value > high else value


# --------------------------------------------------------------------------- safety


class SlewLimiter:
    """Limits how fast a commanded speed may change: at most ``max_accel`` m/s² (per wheel)."""

    def __init__(self, max_accel: float) -> None:
        self.max_accel = max_accel
        self.value = 0.0

    def step(self, target: float, dt: float) -> float:
        """Move towards ``target`` by at most max_accel·dt; returns the new value (m/s)."""
        step = self.max_accel * dt
        self.value = clamp(target, self.value - step, self.value + step)
        return self.value

    def reset(self, value: float = 0.0) -> None:
        self.value = value


STOP_NONE = 0
STOP_LATCHED = 1
"""A ``cmd/stop`` (or halt) latched; it holds until the next motion command."""
STOP_DEADMAN = 2
"""No fresh command for ``deadman_s``."""
STOP_NEVER_COMMANDED = 3
"""No command has arrived since start."""


def gate(fresh_ns: int, stop: bool, now_ns: int, deadman_ns: int) -> int:
    """Why the wheels must be stopped now (one of the STOP_* codes), or STOP_NONE.

    ``fresh_ns`` is the CLOCK_MONOTONIC time of the last motion command (0 = none yet).
    """
    if stop:
        return STOP_LATCHED
    if fresh_ns == 0:
        return STOP_NEVER_COMMANDED
    if now_ns - fresh_ns > deadman_ns:
        return STOP_DEADMAN
    return STOP_NONE


class RestGate:
    """Whether the cycle may rest: run at ``hwbridge.rest_rate_hz`` instead of ``rate_hz``.

    It may once the robot has stood for ``after_ns``: zero targets (a stop, the deadman, no
    command yet, or a command of zero speed), the board's confirmation that it drives zero duty,
    and encoder counts that have not changed. A new motion command (its issue time ``fresh_ns``
    changes, whatever its speed), a wheel that turns (pushed by hand), or the confirmation lost
    (the link) ends the rest at once and starts the wait again. A stop does not: a resting robot
    is stopped already.
    """

    def __init__(self, after_ns: int) -> None:
        self.after_ns = after_ns
        self.resting = False
        self._still_since = -1
        """CLOCK_MONOTONIC ns since which the robot stands (-1: it does not)."""
        self.fresh_ns = 0
        """The issue time of the latest motion command seen (`update`), CLOCK_MONOTONIC ns."""
        self._left = self._right = 0

    def update(self, now_ns: int, stopped: bool, confirmed: bool, fresh_ns: int,
               ticks_left: int, ticks_right: int) -> bool:
        """One period's evidence (``stopped``: zero targets; ``confirmed``: the board confirmed
        zero duty); returns whether the cycle rests from now on."""
        moved = fresh_ns != self.fresh_ns or ticks_left != self._left or ticks_right != self._right
        self.fresh_ns, self._left, self._right = fresh_ns, ticks_left, ticks_right
        if not (stopped and confirmed):
            self._still_since = -1
        elif moved or self._still_since < 0:
            self._still_since = now_ns  # standing from now on
        self.resting = self._still_since >= 0 and now_ns - self._still_since >= self.after_ns
        return self.resting

    def wake(self) -> None:
        """A motion command came while resting (the bus side's kick): rest no more, wait again."""
        self.resting = False
        self._still_since = -1


# --------------------------------------------------------------------------- measurement


class Unwrapper:
    """Turns wrapping 16-bit encoder readings into an unbounded count that never jumps.

    After `rebase` (a reconnect or board RESET) the next reading continues from
    the last unbounded value instead of jumping to the board's new zero.
    """

    def __init__(self) -> None:
        self.count = 0
        self._last: int | None = None

    def update(self, raw: int) -> int:
        """Feed a 16-bit reading (signed or unsigned); returns the unbounded count."""
        if self._last is not None:
            # Difference in 16-bit two's complement: exact while |motion| < 32768 per reading.
            self.count += ((raw - self._last + 0x8000) & 0xFFFF) - 0x8000
        self._last = raw
        return self.count

    def rebase(self) -> None:
        self._last = None


class SpeedEstimator:
    """Rim speed from encoder counts over a sliding time window, without allocating.

    One count is ~0.5 mm, so a difference over one 1 ms cycle is 0 or 1 count at
    walking speeds; the window (e.g. 50 ms) trades lag for resolution. Keeps a
    fixed ring of (time, count) samples.
    """

    def __init__(self, window_s: float, metres_per_tick: float, capacity: int = 256) -> None:
        self.window_ns = int(window_s * 1e9)
        self.k = metres_per_tick
        self._t = [0] * capacity
        self._c = [0] * capacity
        self._head = 0
        self._size = 0
        self.speed = 0.0

    def update(self, t_ns: int, count: int) -> float:
        """Add a sample (monotonic ns, unbounded count); returns the speed in m/s."""
        cap = len(self._t)
        self._t[self._head] = t_ns
        self._c[self._head] = count
        newest = self._head
        self._head = (self._head + 1) % cap
        if self._size < cap:
            self._size += 1
        # Walk back to the oldest sample still inside the window (at least one step back).
        oldest = newest
        for back in range(1, self._size):
            i = (newest - back) % cap
            oldest = i
            if t_ns - self._t[i] >= self.window_ns:
                break
        dt = t_ns - self._t[oldest]
        self.speed = (count - self._c[oldest]) * self.k * 1e9 / dt if dt > 0 else 0.0
        return self.speed

    def reset(self) -> None:
        self._size = 0
        self.speed = 0.0


# --------------------------------------------------------------------------- control


class PIController:
    """Velocity PI controller for one wheel: target and measured rim speed (m/s) -> duty.

    ``kp`` is output units per (m/s), ``ki`` output units per (m/s · s). The
    output is clamped to ±``limit``. Anti-windup by conditional integration: the
    integrator does not grow while the output is saturated in the direction
    of the error, so the wheel does not overshoot after a stall.
    """

    def __init__(self, kp: float, ki: float, limit: float) -> None:
        self.kp, self.ki, self.limit = kp, ki, limit
        self.integral = 0.0
        """Integrated error, m."""
        self.output = 0.0

    def step(self, target: float, measured: float, dt: float) -> float:
        error = target - measured
        candidate = self.integral + error * dt
        unclamped = self.kp * error + self.ki * candidate
        saturated_same_way = (unclamped > self.limit and error > 0) or (
            unclamped < -self.limit and error < 0
        )
        if not saturated_same_way:
            self.integral = candidate
        self.output = clamp(self.kp * error + self.ki * self.integral, -self.limit, self.limit)
        return self.output

    def reset(self) -> None:
        self.integral = 0.0
        self.output = 0.0


class MotionProfile:
    """A timed motion, like the PenguinPi web API's ``/robot/set/velocity?time=T&accel=A``.

    Ramp up over ``accel`` s, hold, ramp down over ``accel`` s: total time T + A,
    distance V·T (PenguinPi report §5.3, made continuous instead of 50 ms steps).
    """

    def __init__(self, left: float, right: float, duration: float, accel: float, start: float) -> None:
        if not duration > 0:
            raise ValueError(f"duration must be > 0 s, got {duration}")
        if accel < 0 or (accel > 0 and duration <= 2 * accel):
            raise ValueError(f"accel must be >= 0 and < duration / 2, got accel {accel} s "
                             f"for duration {duration} s")
        self.left, self.right = left, right
        self.duration, self.accel, self.start = duration, accel, start

    @property
    def end(self) -> float:
        """Time the motion ends (s, same clock as ``start``)."""
        return self.start + self.duration + self.accel

    def fraction(self, now: float) -> float:
        """Fraction of full speed at ``now``: 0..1."""
        t = now - self.start
        a, total = self.accel, self.duration + self.accel
        if t < 0 or t >= total:
            return 0.0
        if a > 0 and t < a:
            return t / a
        if a > 0 and t > self.duration:
            return (total - t) / a
        return 1.0

    def at(self, now: float) -> tuple[float, float, bool]:
        """(left, right, done) at ``now``."""
        f = self.fraction(now)
        return self.left * f, self.right * f, now >= self.end


# --------------------------------------------------------------------------- statistics

HIST_FINE_US = 2000
"""Latencies below this (µs) get 1 µs bins."""
HIST_COARSE_US = 100
"""Above it, 100 µs bins ..."""
HIST_BINS = HIST_FINE_US + 180 + 1
"""... up to 20 ms, and one overflow bin."""


def hist_bin(latency_ns: int) -> int:
    """Histogram bin of a wake-up latency (ns); negative latencies go in bin 0."""
    us = latency_ns // 1000
    if us < HIST_FINE_US:
        return us if us > 0 else 0
    return min(HIST_FINE_US + (us - HIST_FINE_US) // HIST_COARSE_US, HIST_BINS - 1)


def bin_upper_s(index: int) -> float:
    """Upper edge of a histogram bin, s (the overflow bin reports its lower edge)."""
    if index < HIST_FINE_US:
        return (index + 1) * 1e-6
    return (HIST_FINE_US + (index - HIST_FINE_US + 1) * HIST_COARSE_US) * 1e-6


def percentiles(counts: MutableSequence[int] | list[int], qs: tuple[float, ...]) -> list[float]:
    """Percentiles (upper bin edges, s) of a latency histogram; 0.0 when it is empty.

    ``qs`` are fractions, e.g. (0.5, 0.99, 0.999).
    """
    total = sum(counts)
    if total == 0:
        return [0.0 for _ in qs]
    out = []
    for q in qs:
        need = q * total
        running = 0
        for i, c in enumerate(counts):
            running += c
            if running >= need and c:
                out.append(bin_upper_s(i))
                break
    return out
