"""A closed-loop simulation of odometry + localizer against the simulated world, in one process.

Why: the "done" figures of the odometry and the localizer (docs/odometry.md)
need ground truth. This drives the simulator's `World` (motor model, slip,
encoder noise) around a square with a simple wheel-speed driver, feeds the
encoder counts to the real `Odometry` and the odometry poses and simulated
landmark sightings (`icefloe.testing.TruthCamera`) to the real localizer (`localizer.Localizer`,
the same code the service runs), and compares both against the true pose.

The driver steers on the *true* pose (a perfect operator), so every run drives
the same path whatever the estimators do; their errors are measured, not fed back.

Time is simulated: physics at 1 kHz, ``hw/wheels`` samples at `wheels_hz`,
``odom/pose`` at `odom_hz`, camera frames at `camera_hz`. Seeded: a run repeats exactly.
"""

from __future__ import annotations

import logging
import math
import random
from dataclasses import dataclass, field

from ..angles import wrap_angle
from ..config import RobotConfig
from ..schemas import messages as m
from ..sim.world import World
from ..testing import TruthCamera
from .localizer import Localizer
from .odometry import make_odometry

T0_NS = 1_700_000_000 * 10**9
"""Simulated clock origin, ns since the epoch (any fixed value works)."""


@dataclass(frozen=True)
class Scenario:
    """What to simulate."""

    laps: int = 4
    side: float = 1.0
    """Side of the square, m (centred on the origin, driven counter-clockwise)."""
    speed: float = 0.2
    """Cruise speed, m/s."""
    turn_rate: float = 1.5
    """Turn rate on the spot, rad/s."""
    seed: int = 1
    slip: float = 0.0
    """World: relative std dev of ground travel vs rim travel per 1 ms step."""
    encoder_noise: float = 0.0
    """World: relative std dev of counted vs turned wheel angle per 1 ms step."""
    wheels_hz: float = 100.0
    odom_hz: float = 50.0
    camera_hz: float = 15.0
    max_range: float = 3.0
    """Farthest marker the camera reads, m."""
    max_incidence: float = math.radians(70)
    """Markers seen more obliquely than this are not detected, rad."""
    sigma_range: float = 0.02
    """Sighting noise: m, plus `sigma_range_rel` of the range."""
    sigma_range_rel: float = 0.01
    sigma_bearing: float = 0.01
    """rad."""
    outlier_rate: float = 0.0
    """Fraction of sightings replaced by a gross error (a misdetection)."""
    unknown_rate: float = 0.0
    """Fraction of frames with an extra sighting of a marker id not in the map."""
    use_localizer: bool = True
    initial_sigma_xy: float = 0.01
    """The localizer's initial position std dev, m: the robot is placed on the start mark."""
    initial_sigma_theta: float = 0.02
    """rad."""
    initial_error: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """How far off the true start the localizer is told it starts (m, m, rad)."""


@dataclass
class Errors:
    """Position (m) and heading (rad) error of one estimator against the truth."""

    final_pos: float = 0.0
    final_heading: float = 0.0
    max_pos: float = 0.0
    max_heading: float = 0.0

    def add(self, est: tuple[float, float, float], truth: tuple[float, float, float]) -> None:
        self.final_pos = math.hypot(est[0] - truth[0], est[1] - truth[1])
        self.final_heading = abs(wrap_angle(est[2] - truth[2]))
        self.max_pos = max(self.max_pos, self.final_pos)
        self.max_heading = max(self.max_heading, self.final_heading)

    def __str__(self) -> str:
        return (f"final {self.final_pos * 100:.2f} cm {math.degrees(self.final_heading):.2f} deg, "
                f"max {self.max_pos * 100:.2f} cm {math.degrees(self.max_heading):.2f} deg")


@dataclass
class Result:
    odometry: Errors = field(default_factory=Errors)
    localizer: Errors = field(default_factory=Errors)
    sim_seconds: float = 0.0
    distance: float = 0.0
    """Path length driven (truth), m."""
    sightings: int = 0
    injected_outliers: int = 0
    accepted: int = 0
    rejected: int = 0
    unknown: int = 0
    lap_odometry: list[float] = field(default_factory=list)
    """Odometry position error at the end of each lap, m."""
    lap_localizer: list[float] = field(default_factory=list)
    """Localizer position error at the end of each lap, m."""


class Driver:
    """Wheel-speed driver around the square: a line leg, then a turn on the spot, repeated."""

    def __init__(self, world: World, scenario: Scenario) -> None:
        h = scenario.side / 2
        corners = [(h, -h), (h, h), (-h, h), (-h, -h)]
        self.legs: list[tuple[str, float, float, float]] = []  # (kind, target x, target y, heading)
        for _ in range(scenario.laps):
            for k, (cx, cy) in enumerate(corners):
                heading = k * math.pi / 2
                self.legs.append(("line", cx, cy, heading))
                self.legs.append(("turn", cx, cy, wrap_angle(heading + math.pi / 2)))
        self.world, self.s = world, scenario
        self.track = world.geometry.track

    @property
    def done(self) -> bool:
        return not self.legs

    def control(self, truth: tuple[float, float, float]) -> None:
        """Set the wheel duties for the next control period from the true pose."""
        x, y, th = truth
        v = w = 0.0
        while self.legs:
            kind, tx, ty, heading = self.legs[0]
            if kind == "line":
                along = (tx - x) * math.cos(heading) + (ty - y) * math.sin(heading)
                if along < 0.002:
                    self.legs.pop(0)
                    continue
                aim = math.atan2(ty - y, tx - x) if along > 0.05 else heading
                v = min(self.s.speed, max(0.07, 1.5 * along))
                w = 3.0 * wrap_angle(aim - th)
            else:
                err = wrap_angle(heading - th)
                if abs(err) < 0.02:
                    self.legs.pop(0)
                    continue
                w = math.copysign(min(self.s.turn_rate, max(0.9, 3.0 * abs(err))), err)
            break
        self.world.set_duty(*(self._duty(s) for s in (v - w * self.track / 2, v + w * self.track / 2)))

    def _duty(self, speed: float) -> float:
        """Feed-forward duty for a rim speed (the motor's speed is proportional to duty above its dead band)."""
        duty = speed / self.world.steady_speed(1.0)
        if 0.0 < abs(duty) < 0.1:
            duty = math.copysign(0.1, duty)  # just above the 9 % dead band, or the wheel does not turn
        return max(-1.0, min(1.0, duty))


def square_run(config: RobotConfig, scenario: Scenario) -> Result:
    """Drive the square; return the estimators' errors against the truth."""
    rng = random.Random(scenario.seed)
    world = World(config.geometry, seed=scenario.seed, slip=scenario.slip, encoder_noise=scenario.encoder_noise)
    start = (-scenario.side / 2, -scenario.side / 2, 0.0)
    world.set_pose(*start)
    odo = make_odometry(config)
    odo.reset(*start)  # the odometry frame is the map frame at the start, so errors compare directly
    cfg = config
    if scenario.use_localizer:
        import msgspec

        cfg = msgspec.structs.replace(config, localizer=msgspec.structs.replace(
            config.localizer, init="config", initial_x=start[0] + scenario.initial_error[0],
            initial_y=start[1] + scenario.initial_error[1], initial_theta=start[2] + scenario.initial_error[2],
            initial_sigma_xy=scenario.initial_sigma_xy, initial_sigma_theta=scenario.initial_sigma_theta))
    loc = Localizer(cfg, logging.getLogger("icefloe.simrun")) if scenario.use_localizer else None
    camera = TruthCamera(config, rng, max_range=scenario.max_range, max_incidence=scenario.max_incidence,
                         sigma_range=scenario.sigma_range, sigma_range_rel=scenario.sigma_range_rel,
                         sigma_bearing=scenario.sigma_bearing, outlier_rate=scenario.outlier_rate,
                         unknown_rate=scenario.unknown_rate)
    driver = Driver(world, scenario)
    result = Result()

    dt = 0.001
    every_wheels = round(1 / (scenario.wheels_hz * dt))
    every_odom = round(1 / (scenario.odom_hz * dt))
    every_camera = round(1 / (scenario.camera_hz * dt))
    limit = int(600 / dt)  # a run that has not finished in 10 simulated minutes is broken
    prev = world.pose
    for i in range(1, limit):
        world.step(dt)
        truth = world.pose
        result.distance += math.hypot(truth[0] - prev[0], truth[1] - prev[1])
        prev = truth
        stamp = T0_NS + i * 1_000_000
        if i % every_wheels == 0:
            odo.update(stamp, *world.counts())
            legs = len(driver.legs)
            driver.control(truth)
            if len(driver.legs) != legs and len(driver.legs) % 8 == 0:  # a lap ended (8 legs a lap)
                result.lap_odometry.append(math.hypot(odo.x - truth[0], odo.y - truth[1]))
                if loc is not None:
                    ex, ey, _ = loc.ekf.pose
                    result.lap_localizer.append(math.hypot(ex - truth[0], ey - truth[1]))
        if i % every_odom == 0:
            result.odometry.add((odo.x, odo.y, odo.theta), truth)
            if loc is not None:
                loc.on_odometry(m.Pose(stamp=odo.stamp, x=odo.x, y=odo.y, theta=odo.theta))
                result.localizer.add(loc.ekf.pose, truth)
        if loc is not None and i % every_camera == 0:
            loc.on_landmarks(camera.frame(truth, stamp))
            result.localizer.add(loc.ekf.pose, truth)
        if driver.done and max(map(abs, world.wheel_speeds)) < 1e-3:
            result.sim_seconds = i * dt
            break
    else:
        raise RuntimeError("the square run did not finish in 600 simulated seconds")
    result.sightings, result.injected_outliers = camera.sightings, camera.injected_outliers
    result.odometry.add((odo.x, odo.y, odo.theta), world.pose)
    if loc is not None:
        result.localizer.add(loc.ekf.pose, world.pose)
        result.accepted, result.rejected, result.unknown = loc.ekf.accepted, loc.ekf.outliers, loc.ekf.unknown
    return result
