"""The simulated robot's body: two DC gearmotors on a differential-drive base, and a battery.

Everything a board model needs from "the physical world" is here; the board
models (``penguinpi.py``, ``icoboard.py``) only apply PWM duty and read encoder
counts, exactly as the real boards do.

Motor model (from the PenguinPi report, seed 001 §3.2.2, open-loop test of motor A):
the steady encoder rate is proportional to the applied PWM percentage with a
slope of **11.5 counts/s per % PWM**, and the wheel does **not move at 9 % or
less** (static friction: the dead band). The report measured at the pack's
normal voltage; we take that as `NOMINAL_VOLTAGE` and scale the speed with the
battery voltage (a DC motor's speed follows its applied voltage). The speed
approaches its steady value with a first-order lag of `MOTOR_TAU` seconds. The
report gives no time constant; we estimate it from its motor data (report
§3.2.1): stall torque 78.4 mN·m and no-load speed 140 RPM (14.7 rad/s) give a
torque-speed slope b = 0.0784 / 14.7 = 5.3 mN·m·s; half of a ~1 kg robot on a
32.5 mm wheel radius is J = 0.5 · 0.0325² = 5.3e-4 kg·m²; J / b = 0.1 s.

Motor current (report §3.2.1: no-load 190 mA, maximum load 250 mA at full
voltage) is interpolated between those two with the wheel's lag behind its
steady speed, and scaled with the duty: a stalled wheel at full duty draws
250 mA, a free-running one 190 mA.

True wheels (`icefloe.sim.realism.Wheels`, from ``[sim.wheels]`` and ``[sim] profile``): the
encoders count the wheels' turns (``geometry.ticks_per_rev`` a turn), but the ground a turn covers
is the true wheel's circumference, left and right each their own, and the heading follows the true
track. A wheel slips when it accelerates (its ground travel is short by ``slip_accel`` x |a|), the
robot turns less than its wheels say in a fast turn (by ``slip_turn`` x |w|), and each motor has
its own dead band. With no `Wheels` (or the ideal profile's) the robot is exactly ``[geometry]``.

Obstacles (a world's ``[[obstacle]]`` tables, `icefloe.worldmap`): the robot is a disc of
``geometry.radius``. A step that would take it deeper into an obstacle does not happen: the
robot stays where it was, its wheels stand still (they do not count: a robot pushing a wall
sees no motion in its odometry) and `collided` says so; a step out of it, or along it, does.

Battery: a 2S lithium pack, 8.2 V full, open-circuit voltage falling linearly
with the charge drawn (`CAPACITY_AH`), minus an internal-resistance drop. The
Raspberry Pi and the board draw `BASE_CURRENT` all the time.
"""

from __future__ import annotations

import math
import random
import sys
import threading

from icefloe.angles import wrap_angle
from icefloe.config import Geometry
from icefloe.worldmap import Obstacle, clearance

from .realism import Wheels

SLOPE_COUNTS_PER_PCT = 11.5
"""Steady encoder rate per percent of PWM duty, counts/s per % (report Fig. 4)."""
DEAD_BAND_PCT = 9.0
"""No motion at this PWM percentage or less (report §3.2.2); `Wheels` may give each motor its own."""
NOMINAL_VOLTAGE = 7.4
"""Battery voltage at which the slope above holds, V (2S lithium nominal)."""
MOTOR_TAU = 0.1
"""First-order speed lag of wheel + gearmotor under half the robot's mass, s (module docstring)."""
NO_LOAD_CURRENT = 0.19
"""Motor current running free at full voltage, A (ROB-13302 data, report §3.2.1)."""
MAX_LOAD_CURRENT = 0.25
"""Motor current at maximum load (stalled) at full voltage, A."""
BASE_CURRENT = 0.45
"""Raspberry Pi 3B + PenguinPi board + camera, A (assumed)."""
FULL_VOLTAGE = 8.2
"""Open-circuit voltage of a full pack, V."""
EMPTY_VOLTAGE = 6.0
"""Open-circuit voltage when `CAPACITY_AH` has been drawn, V."""
CAPACITY_AH = 2.2
"""Charge between full and empty, A·h."""
INTERNAL_RESISTANCE = 0.1
"""Pack + wiring resistance, ohm."""

CONTACT_MARGIN = 0.002
"""A robot that ran into an obstacle is in contact with it until this far from it, m."""
PLACE_LIMIT = 1000.0
"""`World.place` refuses a position farther than this from the origin, m (no room is that big)."""

WHEELS = ("left", "right")


class World:
    """A differential-drive robot on a flat floor, stepped by the simulator's clock.

    Thread-safe: the clock thread calls `step`, board models call `set_duty` and
    `counts`, tests call the handles; one lock guards the state.
    """

    def __init__(self, geometry: Geometry, *, seed: int = 0, slip: float = 0.0,
                 encoder_noise: float = 0.0, obstacles: tuple[Obstacle, ...] = (),
                 wheels: Wheels | None = None,
                 motor_tau: float = MOTOR_TAU, counts_per_pct: float = SLOPE_COUNTS_PER_PCT) -> None:
        """``slip``: relative std dev of ground travel vs rim travel per step (0 = none).
        ``encoder_noise``: relative std dev of counted vs turned wheel angle per step.
        ``seed``: random seed for both; 0 picks one and prints it so a run can be repeated.
        ``wheels``: the true wheels and motors (None: exactly ``geometry``, dead band 9 %).
        ``motor_tau``, ``counts_per_pct``: another motor than the report's (`MOTOR_TAU`,
        `SLOPE_COUNTS_PER_PCT`), to see what depends on the motor (bench/timed_motion_model.py).
        """
        if not (motor_tau > 0 and counts_per_pct > 0 and math.isfinite(motor_tau + counts_per_pct)):
            raise ValueError("motor_tau and counts_per_pct must be finite and > 0")
        self.motor_tau = motor_tau
        self.counts_per_pct = counts_per_pct
        if slip < 0 or encoder_noise < 0 or not math.isfinite(slip + encoder_noise):
            raise ValueError("slip and encoder_noise must be finite and >= 0")
        if seed == 0:
            seed = random.SystemRandom().randrange(1, 2**31)
            print(f"sim world: seed {seed}", file=sys.stderr)
        self.seed = seed
        self._rng = random.Random(seed)
        self.geometry = geometry
        self.wheels = wheels or Wheels(geometry.wheel_diameter, geometry.wheel_diameter, geometry.track)
        self.slip = slip
        self.encoder_noise = encoder_noise
        self._lock = threading.Lock()
        # m of rim travel per encoder count, as the robot's config believes its wheels
        self._m_per_count = math.pi * geometry.wheel_diameter / geometry.ticks_per_rev
        # ground travel per m of that rim travel: the true wheel's size over the believed one's
        self._roll = (self.wheels.diameter_left / geometry.wheel_diameter,
                      self.wheels.diameter_right / geometry.wheel_diameter)
        self._dead_band = (self.wheels.dead_band_left, self.wheels.dead_band_right)
        self._duty = [0.0, 0.0]
        self._peak = 0.0                     # largest |duty| since `mark`
        self._zero_since = 0.0               # time since which both duties have been 0 (-1: driven)
        self._counts_changed = 0.0              # time of the last change of an encoder count
        self._speed = [0.0, 0.0]             # rim speed, m/s (of the believed wheel: counts x _m_per_count)
        self._counts = [0.0, 0.0]            # fractional encoder position, counts
        self._stalled = [False, False]
        self._pose = (0.0, 0.0, 0.0)
        self._velocity = (0.0, 0.0)          # true (v m/s, w rad/s) over the last step
        self._ocv = FULL_VOLTAGE             # open-circuit voltage, V
        self._rects = [o.rectangle() for o in obstacles]
        self._collided = False
        self._collisions = 0
        self._motor_current = [0.0, 0.0]
        self.time = 0.0
        """Simulated seconds stepped so far."""

    # ------------------------------------------------------------------ inputs

    def set_duty(self, left: float, right: float) -> None:
        """Apply signed PWM duty fractions in [-1, 1] (sign = direction). ValueError otherwise."""
        for name, value in (("left", left), ("right", right)):
            if not (math.isfinite(value) and -1.0 <= value <= 1.0):
                raise ValueError(f"{name} duty must be a finite number in [-1, 1], got {value}")
        with self._lock:
            if left or right:
                self._zero_since = -1.0
            elif self._zero_since < 0:
                self._zero_since = self.time
            self._duty = [float(left), float(right)]
            self._peak = max(self._peak, abs(left), abs(right))

    def mark(self) -> None:
        """Start a new window for `peak_duty`: from now, the largest duty applied."""
        with self._lock:
            self._peak = max(abs(self._duty[0]), abs(self._duty[1]))

    @property
    def zero_duty_since(self) -> float:
        """Simulated time since which both duties have been 0, s (-1 while a wheel is driven)."""
        with self._lock:
            return self._zero_since

    @property
    def counts_changed(self) -> float:
        """Simulated time of the last change of either encoder count, s."""
        with self._lock:
            return self._counts_changed

    @property
    def peak_duty(self) -> float:
        """The largest |duty| (either wheel) applied since the last `mark` (or the start)."""
        with self._lock:
            return self._peak

    def stall(self, wheel: str, on: bool) -> None:
        """Block a wheel ("left" or "right"): it stops turning and draws stall current."""
        index = _wheel_index(wheel)
        with self._lock:
            self._stalled[index] = on
            if on:
                self._speed[index] = 0.0

    def set_battery_voltage(self, volts: float) -> None:
        """Set the pack's open-circuit voltage, V (the terminal voltage sags under load)."""
        if not (math.isfinite(volts) and 0.0 <= volts <= 20.0):
            raise ValueError(f"battery voltage must be in [0, 20] V, got {volts}")
        with self._lock:
            self._ocv = float(volts)

    # ------------------------------------------------------------------ physics

    def steady_speed(self, duty: float, volts: float | None = None, wheel: int = 0) -> float:
        """Rim speed wheel ``wheel`` (0 left, 1 right) settles at for ``duty`` at battery ``volts``, m/s
        (of the wheel as ``geometry`` has it: encoder counts x its m per count)."""
        pct = abs(duty) * 100.0
        if pct <= self._dead_band[wheel]:
            return 0.0
        volts = self._terminal_voltage() if volts is None else volts
        if not self.wheels.battery_sag:
            volts = NOMINAL_VOLTAGE
        counts_per_s = self.counts_per_pct * pct * volts / NOMINAL_VOLTAGE
        return math.copysign(counts_per_s * self._m_per_count, duty)

    def step(self, dt: float) -> None:
        """Advance by ``dt`` seconds: wheel speeds, encoder counts, pose, battery."""
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive number of seconds, got {dt}")
        with self._lock:
            volts = self._terminal_voltage()
            travel = [0.0, 0.0]               # rim travel this step, m
            speed = [0.0, 0.0]
            noise = [0.0, 0.0]                # relative encoder error this step
            decay = math.exp(-dt / self.motor_tau)
            ground = [0.0, 0.0]               # ground travel this step, m
            for i in range(2):
                target = 0.0 if self._stalled[i] else self.steady_speed(self._duty[i], volts, i)
                v0 = self._speed[i]
                # Exact integral of a first-order lag over the step.
                travel[i] = target * dt + (v0 - target) * self.motor_tau * (1.0 - decay)
                speed[i] = target + (v0 - target) * decay
                self._motor_current[i] = self._current(i, target, volts)
                noise[i] = self._rng.gauss(0.0, self.encoder_noise) if self.encoder_noise else 0.0
                # The true wheel's size, less what slips while it speeds up or slows down.
                grip = 1.0 - min(1.0, self.wheels.slip_accel * abs(speed[i] - v0) / dt)
                ground[i] = travel[i] * self._roll[i] * grip
            if self.slip:
                ground = [d * (1.0 + self._rng.gauss(0.0, self.slip)) for d in ground]
            pose = self._integrate(self._pose, ground[0], ground[1], dt)
            if self._rects and self._blocked(pose):
                speed, travel = [0.0, 0.0], [0.0, 0.0]   # against the obstacle: the wheels stand still
                self._velocity = (0.0, 0.0)
                if not self._collided:
                    self._collisions += 1
                self._collided = True
            else:  # still in contact until clear by CONTACT_MARGIN: creeping along a wall is one collision
                self._velocity = ((ground[0] + ground[1]) / 2.0 / dt, wrap_angle(pose[2] - self._pose[2]) / dt)
                self._pose = pose
                self._collided = self._collided and any(
                    clearance(r, pose[0], pose[1]) < self.geometry.radius + CONTACT_MARGIN for r in self._rects)
            for i in range(2):
                self._speed[i] = speed[i]
                if travel[i]:
                    before = math.floor(self._counts[i])
                    self._counts[i] += travel[i] * (1.0 + noise[i]) / self._m_per_count
                    if math.floor(self._counts[i]) != before:
                        self._counts_changed = self.time + dt
            current = BASE_CURRENT + sum(self._motor_current)
            self._ocv = max(0.0, self._ocv - current * dt / 3600.0 / CAPACITY_AH
                            * (FULL_VOLTAGE - EMPTY_VOLTAGE))
            self.time += dt

    def _blocked(self, pose: tuple[float, float, float]) -> bool:
        """Would the robot at ``pose`` overlap an obstacle more than it does now?"""
        radius = self.geometry.radius
        for rect in self._rects:
            after = clearance(rect, pose[0], pose[1])
            if after < radius and after < clearance(rect, self._pose[0], self._pose[1]):
                return True
        return False

    def _current(self, i: int, target: float, volts: float) -> float:
        """Motor current, A: no-load current when at speed, up to max-load when held back."""
        duty = abs(self._duty[i])
        if duty == 0.0:
            return 0.0
        free = abs(target)
        load = 1.0 if free == 0.0 else min(1.0, abs(target - self._speed[i]) / free)
        amps = NO_LOAD_CURRENT + (MAX_LOAD_CURRENT - NO_LOAD_CURRENT) * load
        return amps * duty * volts / NOMINAL_VOLTAGE

    def _integrate(self, pose: tuple[float, float, float], d_left: float,
                   d_right: float, dt: float = 0.001) -> tuple[float, float, float]:
        """Move along the circular arc that the two wheels' ground travels (m) describe over ``dt`` s,
        on the true track, the turn short by what the wheels scrub away at its rate."""
        x, y, theta = pose
        ds = (d_left + d_right) / 2.0
        dtheta = (d_right - d_left) / self.wheels.track
        if self.wheels.slip_turn:
            dtheta *= max(0.0, 1.0 - self.wheels.slip_turn * abs(dtheta) / dt)
        if abs(dtheta) < 1e-12:
            x += ds * math.cos(theta)
            y += ds * math.sin(theta)
        else:
            radius = ds / dtheta
            x += radius * (math.sin(theta + dtheta) - math.sin(theta))
            y -= radius * (math.cos(theta + dtheta) - math.cos(theta))
        return x, y, wrap_angle(theta + dtheta)

    def _terminal_voltage(self) -> float:
        current = BASE_CURRENT + sum(self._motor_current)
        return max(0.0, self._ocv - INTERNAL_RESISTANCE * current)

    # ------------------------------------------------------------------ outputs

    @property
    def pose(self) -> tuple[float, float, float]:
        """True (x m, y m, theta rad CCW in (-pi, pi])."""
        with self._lock:
            return self._pose

    def set_pose(self, x: float, y: float, theta: float) -> None:
        """Place the robot (m, m, rad)."""
        with self._lock:
            self._pose = (float(x), float(y), wrap_angle(theta))

    @property
    def collided(self) -> bool:
        """Did the last step push the robot against an obstacle (and so not move it)?"""
        with self._lock:
            return self._collided

    @property
    def collisions(self) -> int:
        """Times the robot has run into an obstacle (each contact counted once)."""
        with self._lock:
            return self._collisions

    def place(self, x: float, y: float, theta: float) -> None:
        """Pick the robot up and put it down at (x m, y m, theta rad), its wheels at rest.

        Only the pose jumps: the encoders keep their counts (a wheel turned in the air would
        count; one carried does not), so whatever integrates them carries on without a jump.
        ValueError for a non-finite number.
        """
        for name, value in (("x", x), ("y", y), ("theta", theta)):
            if not math.isfinite(value):
                raise ValueError(f"{name} must be a finite number, got {value}")
        for name, value in (("x", x), ("y", y)):
            if abs(value) > PLACE_LIMIT:
                raise ValueError(f"{name} must be within ±{PLACE_LIMIT:g} m of the origin, got {value:g}")
        with self._lock:
            self._pose = (float(x), float(y), wrap_angle(theta))
            self._speed = [0.0, 0.0]
            self._velocity = (0.0, 0.0)

    def reset(self, pose: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        """The world as it started: the robot at ``pose`` (its start: the origin unless the robot
        config says, ``[sim] start_x`` ...) at rest, the pack full, no wheel stalled, no contact
        with an obstacle. The encoders keep their counts (as in `place`)."""
        with self._lock:
            self._pose = (float(pose[0]), float(pose[1]), wrap_angle(pose[2]))
            self._collided = False
            self._speed = [0.0, 0.0]
            self._velocity = (0.0, 0.0)
            self._stalled = [False, False]
            self._ocv = FULL_VOLTAGE

    def counts(self) -> tuple[int, int]:
        """Encoder counts (left, right), unbounded; forward motion increases both."""
        with self._lock:
            return math.floor(self._counts[0]), math.floor(self._counts[1])

    @property
    def wheel_speeds(self) -> tuple[float, float]:
        """True rim speeds (left, right), m/s: the wheels' turning times their true size."""
        with self._lock:
            return self._speed[0] * self._roll[0], self._speed[1] * self._roll[1]

    @property
    def velocity(self) -> tuple[float, float]:
        """The robot's true speed (m/s, forward) and turn rate (rad/s, CCW) over the last step."""
        with self._lock:
            return self._velocity

    @property
    def duty(self) -> tuple[float, float]:
        """PWM duty (left, right) last applied."""
        with self._lock:
            return self._duty[0], self._duty[1]

    @property
    def battery_voltage(self) -> float:
        """Terminal voltage of the pack under the present load, V."""
        with self._lock:
            return self._terminal_voltage()

    @property
    def battery_current(self) -> float:
        """Current drawn from the pack, A."""
        with self._lock:
            return BASE_CURRENT + sum(self._motor_current)


def _wheel_index(wheel: str) -> int:
    if wheel not in WHEELS:
        raise ValueError(f'wheel must be "left" or "right", got {wheel!r}')
    return WHEELS.index(wheel)
