"""hwbridge's pure logic: units, limits, deadman, ramps, PI control, timed motion, statistics."""

from __future__ import annotations

import math

import pytest

from icefloe.config import Geometry
from icefloe.services.hwbridge import control as c


def test_demand_units_follow_the_geometry() -> None:
    g = Geometry()
    k = c.metres_per_tick(g)
    assert k == pytest.approx(math.pi * 0.065 / 384)
    # One demand unit is 10 counts/s ~ 5.32 mm/s.
    assert c.demand_to_speed(1, g) == pytest.approx(5.3178e-3, rel=1e-4)
    assert c.speed_to_demand(0.1, g) == 19            # 0.1 / 5.3178e-3 = 18.8
    assert c.speed_to_demand(-0.1, g) == -19
    assert c.speed_to_demand(5.0, g) == 100            # clamped to the firmware's range
    assert c.speed_to_demand(-5.0, g) == -100
    bigger = Geometry(wheel_diameter=0.130)
    assert c.speed_to_demand(0.1, bigger) == 9         # twice the wheel, half the demand


def test_twist_and_wheel_limits_keep_the_curvature() -> None:
    assert c.twist_to_wheels(0.2, 0.0, 0.156) == (0.2, 0.2)
    left, right = c.twist_to_wheels(0.0, 1.0, 0.156)
    assert (left, right) == pytest.approx((-0.078, 0.078))  # CCW: right wheel forward
    assert c.limit_wheels(0.3, 0.1, 0.5) == (0.3, 0.1, False)
    left, right, clamped = c.limit_wheels(1.0, 0.5, 0.5)
    assert clamped and (left, right) == pytest.approx((0.5, 0.25))


def test_slew_limiter_limits_acceleration_exactly() -> None:
    s = c.SlewLimiter(max_accel=2.0)
    assert s.step(1.0, 0.001) == pytest.approx(0.002)
    for _ in range(99):
        s.step(1.0, 0.001)
    assert s.value == pytest.approx(0.2)
    assert s.step(0.1, 1.0) == 0.1                       # within reach: lands on target
    assert s.step(-1.0, 0.01) == pytest.approx(0.08)


@pytest.mark.parametrize(("fresh", "stop", "now", "want"), [
    (0, False, 10**9, c.STOP_NEVER_COMMANDED),
    (10**9, True, 10**9, c.STOP_LATCHED),
    (10**9, False, 10**9 + 500_000_000, c.STOP_NONE),     # exactly at the deadman: still driving
    (10**9, False, 10**9 + 500_000_001, c.STOP_DEADMAN),
])
def test_gate(fresh: int, stop: bool, now: int, want: int) -> None:
    assert c.gate(fresh, stop, now, deadman_ns=500_000_000) == want


def test_unwrapper_crosses_the_16_bit_wrap_both_ways_and_rebases() -> None:
    u = c.Unwrapper()
    assert u.update(65530) == 0
    assert u.update(4) == 10                  # forward across 65535 -> 0
    assert u.update(65526) == -4              # and back
    assert u.update(-10 & 0xFFFF) == -20 + 16  # signed or unsigned readings alike
    u.rebase()                                # board RESET: counts restart at 0 ...
    assert u.update(0) == -4                  # ... ours continue, no jump
    assert u.update(7) == 3


def test_speed_estimator_over_a_window() -> None:
    k = 0.001
    est = c.SpeedEstimator(window_s=0.05, metres_per_tick=k, capacity=16)
    # 100 counts/s: one count every 10 ms, sampled every 5 ms.
    speed = 0.0
    for i in range(40):
        t = i * 5_000_000
        speed = est.update(t, i // 2)
    assert speed == pytest.approx(0.1, rel=0.11)
    est.reset()
    assert est.update(0, 5) == 0.0


def test_pi_controller_converges_and_does_not_wind_up() -> None:
    pi = c.PIController(kp=2.0, ki=20.0, limit=1.0)
    speed = 0.0
    for _ in range(2000):  # a first-order wheel: speed follows duty with a 50 ms lag
        duty = pi.step(0.3, speed, 0.001)
        speed += (duty * 0.5 - speed) * 0.001 / 0.05
    assert speed == pytest.approx(0.3, abs=0.003)
    # Stalled wheel: the output saturates and the integrator stops growing.
    stalled = c.PIController(kp=2.0, ki=20.0, limit=1.0)
    for _ in range(5000):
        stalled.step(0.3, 0.0, 0.001)
    assert stalled.output == pytest.approx(1.0, abs=0.01)
    assert stalled.integral < 0.1
    # Released, it is back under the limit at once instead of unwinding for seconds.
    assert stalled.step(0.3, 0.3, 0.001) < 1.0


def test_motion_profile_like_the_penguinpi_web_api() -> None:
    p = c.MotionProfile(0.2, 0.1, duration=2.0, accel=0.5, start=10.0)
    assert p.at(10.0) == (0.0, 0.0, False)
    assert p.at(10.25)[:2] == pytest.approx((0.1, 0.05))
    assert p.at(11.0)[:2] == pytest.approx((0.2, 0.1))
    assert p.at(12.25)[:2] == pytest.approx((0.1, 0.05))
    assert p.at(12.5) == (0.0, 0.0, True)
    # distance = V * T
    dt = 0.0005
    dist = sum(p.at(10.0 + i * dt)[0] * dt for i in range(int(3.0 / dt)))
    assert dist == pytest.approx(0.2 * 2.0, rel=1e-3)
    with pytest.raises(ValueError, match="accel"):
        c.MotionProfile(0.1, 0.1, duration=1.0, accel=0.5, start=0.0)
    with pytest.raises(ValueError, match="duration"):
        c.MotionProfile(0.1, 0.1, duration=0.0, accel=0.0, start=0.0)


def test_latency_histogram_percentiles() -> None:
    counts = [0] * c.HIST_BINS
    for latency_us in [10] * 900 + [50] * 99 + [3000]:
        counts[c.hist_bin(latency_us * 1000)] += 1
    p50, p99, p999 = c.percentiles(counts, (0.5, 0.99, 0.999))
    assert p50 == pytest.approx(11e-6)
    assert p99 == pytest.approx(51e-6)
    assert p999 == pytest.approx(51e-6)
    assert c.percentiles(counts, (1.0,)) == [pytest.approx(3.1e-3)]
    assert c.hist_bin(-5000) == 0
    assert c.hist_bin(10**12) == c.HIST_BINS - 1
    assert c.percentiles([0] * c.HIST_BINS, (0.5,)) == [0.0]


def test_demand_dither_delivers_the_average_speed_the_firmware_cannot_hold() -> None:
    g = Geometry()
    d = c.DemandDither(g)
    demands = [d.step(0.15, i * 20_000_000) for i in range(500)]
    assert set(demands) == {25, 30}                  # the two steps around 0.15 m/s
    # What the firmware does with them: trunc(demand / 5) counts per 20 ms.
    mean = sum(int(x / 5) for x in demands) / len(demands) / 0.02 * c.metres_per_tick(g)
    assert mean == pytest.approx(0.15, rel=0.005)
    assert d.step(0.15, 499 * 20_000_000 + 1) == demands[-1]   # held between firmware periods
    assert d.step(-0.15, 501 * 20_000_000) < 0
    assert d.step(0.0, 502 * 20_000_000) == 0 and d.carry == 0.0
    assert c.DemandDither(g).step(9.0, 0) == 100     # clamped to the firmware's ±100
