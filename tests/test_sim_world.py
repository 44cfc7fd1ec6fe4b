"""The simulated world: motor response, kinematics, encoders, battery, handles."""

from __future__ import annotations

import math

import pytest

from icefloe.config import Geometry
from icefloe.sim import world as wmod
from icefloe.sim.world import World

GEOM = Geometry()
M_PER_COUNT = math.pi * GEOM.wheel_diameter / GEOM.ticks_per_rev


def run(world: World, seconds: float, dt: float = 0.001) -> None:
    for _ in range(round(seconds / dt)):
        world.step(dt)


def test_dead_band_and_slope() -> None:
    world = World(GEOM, seed=1)
    world.set_battery_voltage(wmod.NOMINAL_VOLTAGE + wmod.BASE_CURRENT * wmod.INTERNAL_RESISTANCE)
    world.set_duty(0.09, 0.09)                       # 9 %: inside the dead band
    run(world, 0.5)
    assert world.counts() == (0, 0)
    assert world.pose == (0.0, 0.0, 0.0)
    # 40 % duty: 11.5 counts/s per % -> 460 counts/s at nominal voltage (small sag aside).
    expected = wmod.SLOPE_COUNTS_PER_PCT * 40 * M_PER_COUNT
    world.set_duty(0.4, 0.4)
    run(world, 1.0)
    left, right = world.wheel_speeds
    assert left == pytest.approx(expected, rel=0.01) and right == left


def test_first_order_response() -> None:
    world = World(GEOM, seed=1)
    world.set_duty(0.5, 0.5)
    target = world.steady_speed(0.5)
    run(world, wmod.MOTOR_TAU)
    # After one time constant: 1 - 1/e of the way (voltage sag shifts target a little).
    assert world.wheel_speeds[0] == pytest.approx(target * (1 - math.exp(-1)), rel=0.02)


def test_straight_line_matches_counts() -> None:
    world = World(GEOM, seed=1)
    world.set_duty(0.6, 0.6)
    run(world, 2.0)
    x, y, theta = world.pose
    left, right = world.counts()
    assert left == right > 0
    assert x == pytest.approx(left * M_PER_COUNT, abs=M_PER_COUNT)
    assert y == 0.0 and theta == 0.0


def test_spin_in_place_is_ccw_when_right_wheel_forward() -> None:
    world = World(GEOM, seed=1)
    world.set_duty(-0.5, 0.5)
    run(world, 0.3)
    x, y, theta = world.pose
    left, right = world.counts()
    assert left < 0 < right
    assert theta > 0
    assert math.hypot(x, y) < 1e-9
    # Rotation = difference of wheel travels over the track.
    assert theta == pytest.approx((right - left) * M_PER_COUNT / GEOM.track, abs=0.01)


def test_arc_integration_is_exact_on_a_circle() -> None:
    # Constant wheel travels describe a circle; after a full turn the robot is back at the start.
    world = World(GEOM, seed=1)
    d_left, d_right = 0.001, 0.002                  # m per step
    turn = (d_right - d_left) / GEOM.track
    pose = (0.0, 0.0, 0.0)
    steps = round(math.tau / turn)
    for _ in range(steps):
        pose = world._integrate(pose, d_left, d_right)
    leftover = math.tau - steps * turn
    radius = (d_left + d_right) / 2 / turn
    assert math.hypot(pose[0], pose[1]) == pytest.approx(abs(radius * leftover), abs=1e-9)


def test_stall_stops_wheel_and_raises_current() -> None:
    world = World(GEOM, seed=1)
    world.set_duty(0.7, 0.7)
    run(world, 0.5)
    free_current = world.battery_current
    world.stall("left", True)
    before = world.counts()
    run(world, 0.5)
    after = world.counts()
    assert after[0] == before[0] and after[1] > before[1]
    assert world.battery_current > free_current
    world.stall("left", False)
    run(world, 0.5)
    assert world.counts()[0] > after[0]
    with pytest.raises(ValueError, match="wheel must be"):
        world.stall("middle", True)


def test_battery_drains_and_sags_under_load() -> None:
    world = World(GEOM, seed=1)
    idle = world.battery_voltage
    assert idle == pytest.approx(wmod.FULL_VOLTAGE - wmod.BASE_CURRENT * wmod.INTERNAL_RESISTANCE)
    world.set_duty(0.8, 0.8)
    run(world, 1.0)
    assert world.battery_voltage < idle
    assert world.battery_current > wmod.BASE_CURRENT
    world.set_battery_voltage(6.9)
    assert world.battery_voltage == pytest.approx(6.9 - world.battery_current
                                                  * wmod.INTERNAL_RESISTANCE)
    # An hour at the base load draws 0.45 A·h of the 2.2 A·h pack.
    world.set_duty(0.0, 0.0)
    run(world, 0.5)
    world.set_battery_voltage(8.0)
    run(world, 3600.0, dt=1.0)
    drop = 0.45 / wmod.CAPACITY_AH * (wmod.FULL_VOLTAGE - wmod.EMPTY_VOLTAGE)
    assert world.battery_voltage == pytest.approx(8.0 - drop - 0.045, abs=1e-6)


def test_inputs_are_validated() -> None:
    world = World(GEOM, seed=1)
    with pytest.raises(ValueError, match="left duty"):
        world.set_duty(1.5, 0.0)
    with pytest.raises(ValueError, match="right duty"):
        world.set_duty(0.0, math.nan)
    with pytest.raises(ValueError, match="battery voltage"):
        world.set_battery_voltage(-1.0)
    with pytest.raises(ValueError, match="dt must be"):
        world.step(0.0)
    with pytest.raises(ValueError, match="slip"):
        World(GEOM, slip=-0.1)


def test_noise_is_repeatable_with_seed(capsys: pytest.CaptureFixture[str]) -> None:
    def drive(seed: int) -> tuple[tuple[float, float, float], tuple[int, int]]:
        world = World(GEOM, seed=seed, slip=0.2, encoder_noise=0.2)
        world.set_duty(0.5, 0.5)
        run(world, 1.0)
        return world.pose, world.counts()

    assert drive(5) == drive(5)
    assert drive(5) != drive(6)
    picked = World(GEOM)
    assert picked.seed != 0
    assert f"seed {picked.seed}" in capsys.readouterr().err
