"""The virtual car (icefloe/motion/car.py) on a simulated clock, and its config: no bus, no
processes, every time passed in. hwbridge's ``cmd/car`` path: tests/test_hwbridge_car.py; the car
on the simulated robot: tests/test_hwbridge_car_sim.py."""

from __future__ import annotations

import math
from pathlib import Path

import msgspec
import pytest

from icefloe import config
from icefloe.config import Car
from icefloe.errors import ConfigError
from icefloe.motion.car import VirtualCar, car_twist, turn_radius
from icefloe.motion.diffdrive import limit_wheels, twist_to_wheels
from icefloe.schemas import messages as m

TRACK = 0.156
CAR = Car(wheelbase=0.15, max_steer=0.6, steer_rate=1.5)


def centre_radius(left: float, right: float, track: float = TRACK) -> float:
    """Radius of the circle the wheels' midpoint runs on at these rim speeds, m."""
    return (left + right) / (right - left) * track / 2


@pytest.mark.parametrize("steer", [0.1, 0.3, -0.45, 0.6])
def test_the_wheels_turn_about_the_cars_centre(steer: float) -> None:
    """At a steady angle the base turns on a circle of wheelbase / tan(steer), left for a positive angle."""
    car = VirtualCar(CAR, TRACK, max_wheel_speed=0.5)
    car.command(0.15, steer, 0.0)
    car.advance(2.0)  # the steering has arrived
    assert car.steer == steer
    w = car.wheels
    assert abs(centre_radius(w.left, w.right)) == pytest.approx(turn_radius(steer, CAR.wheelbase), rel=1e-12)
    assert (w.right > w.left) == (steer > 0)
    assert (w.left + w.right) / 2 == pytest.approx(0.15)


def test_a_car_facing_backward_drives_the_robot_backward_turning_the_same_way() -> None:
    v_f, w_f = car_twist(0.1, 0.3, 0.15, "forward")
    v_b, w_b = car_twist(0.1, 0.3, 0.15, "backward")
    assert v_b == -v_f and w_b == w_f > 0
    car = VirtualCar(msgspec.structs.replace(CAR, facing="backward"), TRACK, 0.5)
    assert car.theta == math.pi  # the car's heading: the robot's back
    car.command(0.1, 0.0, 0.0)
    car.advance(1.0)
    assert car.wheels.left == car.wheels.right == pytest.approx(-0.1)
    assert car.x == pytest.approx(-0.1) and abs(car.y) < 1e-12


def test_the_steering_turns_at_its_rate_on_a_simulated_clock() -> None:
    """A step from straight to full left, then to full right: a ramp at 1.5 rad/s each way,
    stepped at 50 Hz as hwbridge steps it; the wheels follow every step."""
    car = VirtualCar(CAR, TRACK, 0.5)
    car.command(0.1, 0.6, 0.0)
    seen = []
    for i in range(1, 101):
        t = i * 0.02
        changed = car.advance(t)
        seen.append((t, car.steer, changed))
    assert [s for t, s, _ in seen if t <= 0.4 + 1e-9] == pytest.approx([1.5 * t for t, _, _ in seen[:20]])
    assert all(s == 0.6 for t, s, _ in seen if t >= 0.4 + 1e-9)
    assert all(c for t, _, c in seen if t < 0.4) and not any(c for t, _, c in seen if t > 0.41)
    car.command(0.1, -0.6, 2.0)  # full right: 1.2 rad at 1.5 rad/s = 0.8 s
    car.advance(2.4)
    assert car.steer == pytest.approx(0.0)
    car.advance(2.8)
    assert car.steer == pytest.approx(-0.6)
    w = car.wheels
    assert centre_radius(w.left, w.right) == pytest.approx(-turn_radius(0.6, 0.15))


def test_beyond_the_largest_angle_it_is_clipped_and_says_so() -> None:
    car = VirtualCar(CAR, TRACK, 0.5)
    made = car.command(0.1, 1.2, 0.0)
    assert made.clipped and made.steer_target == 0.6
    assert not car.command(0.1, -0.6, 0.1).clipped
    assert car.command(0.1, -5.0, 0.2).steer_target == -0.6


def test_a_turn_the_wheels_cannot_make_at_that_speed_is_slowed_keeping_its_radius() -> None:
    car = VirtualCar(CAR, TRACK, max_wheel_speed=0.5)
    car.command(0.5, 0.6, 0.0)
    car.advance(1.0)
    w = car.wheels
    assert w.slowed and w.asked == 0.5 and max(abs(w.left), abs(w.right)) == pytest.approx(0.5)
    assert w.v < 0.5 and (w.left + w.right) / 2 == pytest.approx(w.v)
    assert centre_radius(w.left, w.right) == pytest.approx(turn_radius(0.6, 0.15))


@pytest.mark.parametrize("v", [1e308, -1.7e308, 3.0])
def test_a_huge_speed_is_the_wheels_limit_never_inf_or_nan(v: float) -> None:
    """What a hostile student sends: the largest finite floats (tan(0.6) / 0.15 times them overflow)."""
    car = VirtualCar(CAR, TRACK, max_wheel_speed=0.5)
    car.command(v, 0.6, 0.0)
    car.advance(1.0)
    w = car.wheels
    assert w.slowed and all(math.isfinite(x) for x in (w.left, w.right, w.v, car.x, car.y, car.theta))
    assert max(abs(w.left), abs(w.right)) == pytest.approx(0.5)
    assert centre_radius(w.left, w.right) == pytest.approx(turn_radius(0.6, 0.15))  # the centre on the left


def test_a_twist_that_overflows_is_clamped_not_nan() -> None:
    left, right = twist_to_wheels(1.79e308, 1e308, TRACK)
    assert math.isinf(right)
    assert limit_wheels(left, right, 0.5) == (0.0, 0.5, True)


def test_the_bicycle_pose_runs_the_circle_and_stops_with_a_stop() -> None:
    """A quarter circle at a steady angle lands where the geometry says; after `hold` (a stop)
    the pose stands still and the steering stays where it was."""
    car = VirtualCar(CAR, TRACK, 0.5)
    car.steer = car.steer_target = 0.4  # already steered: the circle from the start
    car.command(0.1, 0.4, 0.0)
    radius = turn_radius(0.4, 0.15)
    quarter = math.pi / 2 * radius / 0.1
    steps = 500
    for i in range(1, steps + 1):
        car.advance(quarter * i / steps)
    assert (car.x, car.y) == pytest.approx((radius, radius), abs=1e-9)
    assert car.theta == pytest.approx(math.pi / 2)
    car.hold(quarter)
    car.advance(quarter + 5.0)
    assert (car.x, car.y) == pytest.approx((radius, radius), abs=1e-9)
    assert car.steer == 0.4 and car.wheels.left == car.wheels.right == 0.0
    state = car.state(123)
    assert isinstance(state, m.CarState) and not state.driving and state.v == 0.0


# ---------------------------------------------------------------------------- config


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "robot.toml"
    path.write_text(f'extends = "sim"\n{text}\n')
    return path


@pytest.mark.parametrize(("toml", "named"), [
    ("[car]\nwheelbase = 0.0", "car.wheelbase: Expected `float` >= 0.02"),
    ("[car]\nmax_steer = -0.1", "car.max_steer: Expected `float` > 0.0"),
    ("[car]\nmax_steer = 1.5", "car.max_steer: Expected `float` <= 1.3"),
    ("[car]\nsteer_rate = nan", "car.steer_rate: Expected `float` > 0.0"),
    ("[car]\nfacing = \"sideways\"", "car.facing: Invalid enum value 'sideways'"),
    ("[car]\nwheel_base = 0.2", "[car]: Object contains unknown field `wheel_base`"),
    ("[geometry]\ntrack = 0.156\n[car]\nwheelbase = 0.05\nmax_steer = 1.0",  # the drawing's track: the figures
     "car.max_steer: 1 rad turns about a point 0.032 m from the rear axle's centre, inside the wheels (0.078 m "
     "each side): a car's inner wheel would run backwards; at most 0.570 rad for wheelbase 0.05 m"),
])
def test_a_bad_car_starts_nothing_and_says_why_in_one_line(tmp_path: Path, toml: str, named: str) -> None:
    path = write(tmp_path, toml)
    with pytest.raises(ConfigError) as refused:
        config.load(path)
    assert str(refused.value) == f"{path}: {named}"


def test_the_shipped_configs_have_a_car() -> None:
    car = config.load("sim").car
    assert (car.wheelbase, car.max_steer, car.steer_rate, car.facing) == (0.15, 0.6, 1.5, "forward")
