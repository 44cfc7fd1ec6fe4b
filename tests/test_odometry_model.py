"""Unit tests of the pure dead-reckoning model (icefloe/estimation/odometry.py)."""

from __future__ import annotations

import math

import pytest

from icefloe.estimation.odometry import (
    Event,
    Geometry,
    Limits,
    Odometry,
    count_delta,
    sinc,
)

GEO = Geometry(wheel_diameter=0.065, track=0.156, ticks_per_rev=384)
K = GEO.metres_per_tick  # 5.3178e-4 m per count
MS = 1_000_000  # ns


def counts(metres: float) -> int:
    return round(metres / K)


def drive(odo: Odometry, left_m_per_step: float, right_m_per_step: float, steps: int,
          t0: int = 0, dt_ns: int = 10 * MS, start: tuple[int, int] = (0, 0)) -> tuple[int, int, int]:
    """Feed `steps` samples of constant wheel travel (as exact fractional counts, floored like a real
    encoder); returns the last (stamp, left, right)."""
    stamp, left, right = t0, *start
    for i in range(1, steps + 1):
        stamp = t0 + i * dt_ns
        left = start[0] + math.floor(i * left_m_per_step / K)
        right = start[1] + math.floor(i * right_m_per_step / K)
        step = odo.update(stamp, left, right)
        assert step.event is Event.MOVED, step.describe()
    return stamp, left, right


def fresh(**limits: float) -> Odometry:
    odo = Odometry(GEO, Limits(**limits))
    assert odo.update(0, 0, 0).event is Event.FIRST
    return odo


# ---------------------------------------------------------------- helpers


def test_sinc_is_continuous_at_zero() -> None:
    assert sinc(0.0) == 1.0
    for u in (1e-5, 1e-4, 2e-4, 0.3):
        assert sinc(u) == pytest.approx(math.sin(u) / u, rel=1e-12)


@pytest.mark.parametrize(("old", "new", "delta"), [
    (32767, -32768, 1), (32760, -32760, 16), (-32768, 32767, -1), (-32760, 32760, -16),
    (100, 90, -10), (-5, 5, 10),
    (40000, 40010, 10), (32767, 32769, 2), (-40000, -40010, -10),  # unwrapped counts beyond int16
])
def test_count_delta_across_16_bit_wrap_both_directions(old: int, new: int, delta: int) -> None:
    assert count_delta(new, old) == delta


# ---------------------------------------------------------------- motion


def test_straight_line() -> None:
    odo = fresh()
    drive(odo, 0.002, 0.002, 500)  # 1 m at 0.2 m/s, sampled at 100 Hz
    assert odo.x == pytest.approx(1.0, abs=K)
    assert odo.y == pytest.approx(0.0, abs=1e-12)
    assert odo.theta == 0.0
    v, w = odo.speeds()
    assert v == pytest.approx(0.2, rel=0.02)
    assert w == pytest.approx(0.0, abs=1e-9)


def test_straight_line_backwards() -> None:
    odo = fresh()
    drive(odo, -0.002, -0.002, 250)
    assert odo.x == pytest.approx(-0.5, abs=2 * K)
    assert odo.speeds()[0] == pytest.approx(-0.2, rel=0.02)


def test_pure_rotation_counter_clockwise_is_positive() -> None:
    odo = fresh()
    quarter = 0.25 * math.pi * GEO.track  # rim travel for 90 deg on the spot
    drive(odo, -quarter / 100, quarter / 100, 100)
    assert odo.theta == pytest.approx(math.pi / 2, abs=2 * K / GEO.track)
    assert math.hypot(odo.x, odo.y) < 1e-3  # the centre stays put (within a count)
    assert odo.speeds()[1] == pytest.approx(math.pi / 2, rel=0.03)  # 90 deg in 1 s


def test_full_turns_wrap_theta() -> None:
    odo = fresh()
    rim = 0.5 * math.pi * GEO.track  # rim travel of each wheel for half a turn on the spot
    seen, stamp = [], 0
    for n in range(7):  # 3.5 turns clockwise, each half turn in 20 samples 20 ms apart
        for i in range(1, 21):
            stamp += 20 * MS
            travel = (n + i / 20) * rim
            assert odo.update(stamp, counts(travel), counts(-travel)).event is Event.MOVED
            assert -math.pi < odo.theta <= math.pi
        seen.append(odo.theta)
    assert seen[1] == pytest.approx(0.0, abs=0.01)  # one full turn
    assert abs(seen[-1]) == pytest.approx(math.pi, abs=0.01)  # 3.5 turns
    assert odo.speeds()[1] == pytest.approx(-math.pi / 0.4, rel=0.02)


def test_arc_matches_the_circle() -> None:
    # Quarter circle of radius R: left wheel on R - b/2, right on R + b/2, in 400 samples.
    radius, n = 0.5, 400
    arc = 0.5 * math.pi
    left, right = arc * (radius - GEO.track / 2), arc * (radius + GEO.track / 2)
    odo = fresh()
    drive(odo, left / n, right / n, n)
    assert odo.theta == pytest.approx(arc, abs=0.005)
    assert odo.x == pytest.approx(radius, abs=0.002)
    assert odo.y == pytest.approx(radius, abs=0.002)


def test_arc_integration_is_exact_for_one_big_sample() -> None:
    # One sample covering a whole semicircle: the first-order (Euler or midpoint-without-sinc)
    # step would land at y = pi * R; the arc step lands on the circle at y = 2R.
    radius = 0.3
    left = math.pi * (radius - GEO.track / 2)
    right = math.pi * (radius + GEO.track / 2)
    odo = fresh(max_wheel_speed=10.0)
    odo.update(1000 * MS, counts(left), counts(right))
    assert odo.x == pytest.approx(0.0, abs=2e-3)
    assert odo.y == pytest.approx(2 * radius, abs=2e-3)
    assert odo.theta == pytest.approx(math.pi, abs=0.01)


def test_counts_wrapping_through_int16_in_both_directions() -> None:
    """Raw 16-bit counters: forward through +32767 -> -32768, then back again, lands where it started."""
    odo = Odometry(GEO)
    start = 32767 - 200
    odo.update(0, start, start)
    step_counts = 3
    c = start
    stamp = 0
    for _ in range(200):  # forward 600 counts: crosses +32767 -> -32768
        stamp += 10 * MS
        c += step_counts
        raw = (c + 32768) % 65536 - 32768
        assert odo.update(stamp, raw, raw).event is Event.MOVED
    assert odo.x == pytest.approx(600 * K, rel=1e-9)
    for _ in range(200):  # back 600 counts: crosses -32768 -> +32767
        stamp += 10 * MS
        c -= step_counts
        raw = (c + 32768) % 65536 - 32768
        assert odo.update(stamp, raw, raw).event is Event.MOVED
    assert odo.x == pytest.approx(0.0, abs=1e-9)
    assert odo.theta == 0.0


def test_skipped_samples_lose_no_motion() -> None:
    odo = fresh()
    # Only every 7th sample of a 0.2 m/s drive arrives.
    for i in range(7, 701, 7):
        assert odo.update(i * 10 * MS, counts(i * 0.002), counts(i * 0.002)).event is Event.MOVED
    assert odo.x == pytest.approx(700 * 0.002, abs=K)


def test_reset_sets_pose_and_keeps_integrating() -> None:
    odo = fresh()
    stamp, left, right = drive(odo, 0.002, 0.002, 100)
    odo.reset(1.0, 2.0, 4.0)
    assert (odo.x, odo.y, odo.theta) == (1.0, 2.0, pytest.approx(4.0 - 2 * math.pi))
    odo.update(stamp + 10 * MS, left + counts(0.002), right + counts(0.002))
    assert odo.x == pytest.approx(1.0 + 0.002 * math.cos(4.0), abs=K)
    with pytest.raises(ValueError, match="finite"):
        odo.reset(math.nan, 0.0, 0.0)


# ---------------------------------------------------------------- bad input


def test_timestamp_backwards_is_not_integrated() -> None:
    odo = fresh()
    stamp, left, right = drive(odo, 0.002, 0.002, 50)
    before = (odo.x, odo.y, odo.theta)
    step = odo.update(stamp - 5 * MS, left + 4, right + 4)
    assert step.event is Event.BACKWARDS
    assert "backwards" in step.describe() and "dt=-0.0050" in step.describe()
    assert (odo.x, odo.y, odo.theta) == before
    # Motion goes on from the new reference.
    assert odo.update(stamp + 5 * MS, left + 8, right + 8).event is Event.MOVED
    assert odo.x == pytest.approx(before[0] + 4 * K, abs=1e-12)


def test_gap_without_motion_changes_nothing_and_is_reported() -> None:
    odo = fresh()
    stamp, left, right = drive(odo, 0.002, 0.002, 50)
    before = (odo.x, odo.y, odo.theta)
    step = odo.update(stamp + 1000 * MS, left, right)
    assert step.event is Event.GAP and step.dt == pytest.approx(1.0)
    assert (odo.x, odo.y, odo.theta) == before


def test_gap_with_plausible_motion_is_integrated() -> None:
    # Counts are cumulative: 0.1 m in a 1 s gap is motion the wheels really made.
    odo = fresh()
    stamp, left, right = drive(odo, 0.002, 0.002, 50)
    x0 = odo.x
    assert odo.update(stamp + 1000 * MS, left + counts(0.1), right + counts(0.1)).event is Event.GAP
    assert odo.x == pytest.approx(x0 + 0.1, abs=K)


@pytest.mark.parametrize(("d_left", "d_right", "what"), [
    (5000, 5000, "huge jump forward"),
    (-20000, -20000, "encoder reset to 0 from 20000"),
    (0, -400, "one wheel jumps back (the old code integrated |d| <= 400)"),
    (40, 40, "21 mm in 10 ms = 2 m/s"),
])
def test_implausible_jump_is_not_integrated(d_left: int, d_right: int, what: str) -> None:
    odo = fresh()
    stamp, left, right = drive(odo, 0.002, 0.002, 50)
    before = (odo.x, odo.y, odo.theta)
    step = odo.update(stamp + 10 * MS, left + d_left, right + d_right)
    assert step.event is Event.JUMP, what
    assert f"dL={d_left}" in step.describe()
    assert (odo.x, odo.y, odo.theta) == before
    # The jumped-to counts are the new reference: the next small step integrates normally.
    assert odo.update(stamp + 20 * MS, left + d_left + 3, right + d_right + 3).event is Event.MOVED
    assert odo.x == pytest.approx(before[0] + 3 * K, abs=1e-12)


def test_bridge_restart_counts_jump_back_to_zero() -> None:
    odo = Odometry(GEO)
    odo.update(0, 123456, 654321)
    odo.update(10 * MS, 123460, 654325)
    x = odo.x
    assert odo.update(20 * MS, 0, 0).event is Event.JUMP
    assert odo.x == x
    assert odo.update(30 * MS, 2, 2).event is Event.MOVED


@pytest.mark.parametrize("sample", [(1.5, 0, 0), (0, 1.0, 2), (0, True, 2), (0, 0, None)])
def test_non_integer_samples_are_ignored(sample: tuple) -> None:
    odo = fresh()
    assert odo.update(*sample).event is Event.BAD
    assert (odo.x, odo.y, odo.theta, odo.stamp) == (0.0, 0.0, 0.0, 0)


def test_event_log_reports_each_kind_then_limits_a_storm() -> None:
    import logging

    from icefloe.estimation.odometry import EventLog, Step

    lines: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            lines.append(record.getMessage())

    log = logging.getLogger("test.odometry.events")
    log.addHandler(Keep())
    log.setLevel(logging.INFO)
    now = [0.0]
    events = EventLog(log, clock=lambda: now[0], burst=2)
    events.note(Step(Event.MOVED, 1, 1, 0.01))  # normal motion: never logged
    for i in range(50):  # a board resetting 50 times within a second
        events.note(Step(Event.JUMP, -1000 - i, -1000, 0.01))
    events.note(Step(Event.BACKWARDS, 0, 0, -0.02))  # another kind still gets through
    assert len(lines) == 3
    assert "dL=-1000" in lines[0] and "dL=-1001" in lines[1] and "backwards" in lines[2]
    now[0] = 1.5
    events.note(Step(Event.JUMP, -7, -7, 0.01))
    assert lines[-2] == "48 more lines like these not shown in 1.5 s: 48 hw/wheels jump" and "dL=-7" in lines[-1]
    assert events.counts[Event.JUMP] == 51 and events.counts[Event.MOVED] == 1
