"""The virtual car: a bicycle-model (Ackermann-steered) car on the differential base.

A car turns about a point on its rear axle's line, at radius ``wheelbase / tan(steer)`` from the
axle's centre; a differential base turns about a point on its wheels' axle. So with its rear
axle on the drive wheels' axle the base *is* the car, exactly: forward speed v, turn rate
``v * tan(steer) / wheelbase`` (the PenguinPi report's "virtual Ackerman-steered configuration",
§2). `VirtualCar` adds what makes it a car rather than a unicycle:

* the steering turns at most ``car.steer_rate`` rad/s towards the angle asked for, and never past
  ``car.max_steer``;
* the bicycle model's pose of the rear axle, integrated from exactly what was applied, held
  between steps (what the wheels were told: the model a student compares with odometry);
* the wheels' limit: when the outer wheel would pass ``max_wheel_speed`` the car is slowed, its
  turn kept (the path the model predicts stays the path).

Times are seconds on one monotonic clock, passed in (`command`, `advance`, `hold`); nothing
here reads a clock, so a test drives it exactly. hwbridge holds one and steps it
(services/hwbridge/bridge.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..angles import wrap_angle
from ..config import Car
from ..schemas import messages as m
from .diffdrive import twist_to_wheels


def car_twist(v: float, steer: float, wheelbase: float, facing: str = "forward") -> tuple[float, float]:
    """A car's speed (m/s, the car's forward) and steering angle (rad, left positive) as the
    base's twist (v m/s along the robot's front, w rad/s CCW). A car facing the robot's back
    drives the robot backwards; its turn rate is the same (CCW is CCW whichever end leads)."""
    w = v * math.tan(steer) / wheelbase
    return (v if facing == "forward" else -v), w


def turn_radius(steer: float, wheelbase: float) -> float:
    """Radius of the rear axle centre's circle at ``steer`` rad, m (inf when straight)."""
    t = math.tan(abs(steer))
    return wheelbase / t if t > 0 else math.inf


def step_towards(value: float, target: float, most: float) -> float:
    """``value`` moved towards ``target`` by at most ``most`` (>= 0)."""
    if target > value:
        return min(target, value + most)
    return max(target, value - most)


@dataclass(frozen=True, slots=True)
class Command:
    """What `VirtualCar.command` made of a command: the angle it steers towards and whether
    that was clipped to ``max_steer``."""

    steer_target: float
    clipped: bool


@dataclass(frozen=True, slots=True)
class Wheels:
    """The rim speeds for the car now (m/s), the car's speed applied (m/s) and whether it was
    slowed for ``max_wheel_speed`` (from ``asked`` m/s)."""

    left: float
    right: float
    v: float
    slowed: bool
    asked: float


class VirtualCar:
    """One virtual car: its steering, its speed and its bicycle-model pose, stepped in time.

    ``car``: the ``[car]`` config; ``track``: the base's track, m; ``max_wheel_speed``: m/s.
    """

    def __init__(self, car: Car, track: float, max_wheel_speed: float, now: float = 0.0) -> None:
        self.car = car
        self.track = track
        self.max_wheel_speed = max_wheel_speed
        self.t = now
        """Time of the last step, s."""
        self.steer = 0.0
        """Steering angle applied since `t`, rad (after the rate limit)."""
        self.steer_target = 0.0
        self.v_asked = 0.0
        """The command's speed, m/s (0 while not driving)."""
        self.driving = False
        self.x = self.y = 0.0
        self.theta = 0.0 if car.facing == "forward" else math.pi
        self._wheels = self._compute()

    # ------------------------------------------------------------------ inputs

    def command(self, v: float, steer: float, now: float) -> Command:
        """A ``cmd/car`` that may drive, at ``now``: the car steers towards ``steer`` (clipped to
        ``max_steer``) at its rate from where it is, at ``v`` m/s."""
        self.advance(now)
        limit = self.car.max_steer
        target = max(-limit, min(limit, steer))
        self.steer_target, self.v_asked, self.driving = target, v, True
        self._wheels = self._compute()
        return Command(target, target != steer)

    def hold(self, now: float) -> None:
        """The car no longer drives from ``now`` (a stop, the deadman, another command): speed 0,
        the steering stays where it is."""
        self.advance(now)
        self.v_asked, self.driving = 0.0, False
        self.steer_target = self.steer
        self._wheels = self._compute()

    # ------------------------------------------------------------------ time

    def advance(self, now: float) -> bool:
        """Integrate the pose up to ``now`` with what was applied since the last step, then turn
        the steering towards its target by what its rate allows in that time. Returns whether the
        wheel speeds changed (an earlier ``now`` than the last step counts as no time)."""
        dt = now - self.t
        if dt <= 0:
            return False
        self.t = now
        self._integrate(self._wheels.v, dt)
        steer = step_towards(self.steer, self.steer_target, self.car.steer_rate * dt)
        if steer == self.steer:
            return False
        self.steer = steer
        before = self._wheels
        self._wheels = self._compute()
        return (self._wheels.left, self._wheels.right) != (before.left, before.right)

    def _integrate(self, v: float, dt: float) -> None:
        """The rear axle along the arc of speed ``v`` at the applied steering for ``dt`` s (exact)."""
        if v == 0.0:
            return
        ds = v * dt
        dtheta = ds * math.tan(self.steer) / self.car.wheelbase
        if abs(dtheta) < 1e-12:
            self.x += ds * math.cos(self.theta)
            self.y += ds * math.sin(self.theta)
        else:
            radius = ds / dtheta
            self.x += radius * (math.sin(self.theta + dtheta) - math.sin(self.theta))
            self.y -= radius * (math.cos(self.theta + dtheta) - math.cos(self.theta))
        self.theta = wrap_angle(self.theta + dtheta)

    # ------------------------------------------------------------------ outputs

    def _compute(self) -> Wheels:
        # No wheel runs slower than the car (the outer one runs faster): a speed beyond the wheels'
        # limit is that limit before anything else, so a huge one cannot overflow into inf and NaN.
        v = max(-self.max_wheel_speed, min(self.max_wheel_speed, self.v_asked))
        v_body, w = car_twist(v, self.steer, self.car.wheelbase, self.car.facing)
        left, right = twist_to_wheels(v_body, w, self.track)
        fastest = max(abs(left), abs(right))
        if fastest <= self.max_wheel_speed:
            return Wheels(left, right, v, v != self.v_asked, self.v_asked)
        scale = self.max_wheel_speed / fastest  # both wheels alike: the curvature, the car's path, kept
        return Wheels(left * scale, right * scale, v * scale, True, self.v_asked)

    @property
    def wheels(self) -> Wheels:
        """The rim speeds for what is applied now."""
        return self._wheels

    def state(self, stamp: int) -> m.CarState:
        """``car/state`` as of the last step."""
        return m.CarState(stamp=stamp, v=self._wheels.v, steer=self.steer, steer_target=self.steer_target,
                          x=self.x, y=self.y, theta=self.theta, driving=self.driving)
