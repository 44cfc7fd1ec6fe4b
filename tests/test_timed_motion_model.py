"""Timed and ramped motions cover V·T on the PenguinPi firmware model, in simulated time.

`bench/timed_motion_model.py` runs what the web API and hwbridge do with
``/robot/set/velocity?value=V,V&time=T&accel=A`` (the web API's T', hwbridge's profile, slew
limit, dither, exchanges and stop) against the firmware model's 20 ms integer PI loop driving the
simulated motors, on one simulated clock: exact and repeatable, no processes. The firmware's
control step falls anywhere against a motion's start; with it a motion may cover one 20 ms step
of V more or less (4 % of a 0.5 s motion at 20 units, as on the real board). So: the mean over
the control phases is within 1 % of V·T for T from 1 s to 5 s at the course's speeds (20 to 90
units), unramped and with ``accel=0.2`` (whose profile also covers V·T), within 1.2 % at 0.5 s
(measured: 1.1 % at 20 units with ``accel=0.2`` and at 90 without); each single motion is within
1 % + V·20 ms. About 10 s here (5 s on an idle machine).
"""

from __future__ import annotations

import statistics
import sys

import pytest
from conftest import ROOT

from icefloe.services.webapi import timing

sys.path.insert(0, str(ROOT / "bench"))
from timed_motion_model import UNIT, Motor, drive, error, held

PHASES = (0, 5, 10, 15)
"""Where the firmware's control step falls after a motion's start, ms (the lead table's mean)."""


@pytest.mark.parametrize("accel", [0.0, 0.2])
@pytest.mark.parametrize("demand", [20, -40, 65, 90])
def test_timed_motions_cover_v_times_t_from_half_a_second_to_two(demand: int, accel: float) -> None:
    for t in (0.5, 1.0, 2.0):
        errors = error(abs(demand), t, accel, phases=PHASES)
        # at 0.5 s the lead table's interpolation leaves up to 1.1 % (20 units with accel=0.2, 90 without)
        assert abs(statistics.mean(errors)) < (0.012 if t < 1 else 0.01), (demand, t, accel, errors)
        assert max(abs(e) for e in errors) < 0.01 + 0.020 / t, (demand, t, accel, errors)


@pytest.mark.parametrize("accel", [0.0, 0.2, 0.5])
def test_five_seconds(accel: float) -> None:
    errors = error(40, 5.0, accel, phases=PHASES)
    assert max(abs(e) for e in errors) < 0.01, (accel, errors)


def test_without_the_lead_they_were_not() -> None:
    """The lead table is what does it: without it, 40 units for 0.5 s go 4 % too far, 40 ramped
    over 0.2 s for 1 s 4.5 % (bench/timed_motion_model.py's reference column)."""
    assert statistics.mean(error(40, 0.5, 0.0, lead=False, phases=PHASES)) > 0.03
    assert statistics.mean(error(40, 1.0, 0.2, lead=False, phases=PHASES)) > 0.03


def test_backwards_and_the_model_are_the_same_as_forwards() -> None:
    """A motion backwards is the mirror of one forwards within a count or so (the table is by the
    speed's size; the firmware's integer division truncates towards zero both ways)."""
    t = held(40, 1.0, 0.0)
    forward = drive(40, t, 0.0)
    assert drive(-40, t, 0.0) == pytest.approx(-forward, rel=0.005)
    assert forward == pytest.approx(40 * UNIT * 1.0, rel=0.02)


def test_the_lead_is_interpolated_within_the_table_and_clamped_beyond() -> None:
    row, column = timing.LEAD_DEMANDS.index(40), timing.LEAD_ACCELS.index(0.2)
    assert timing.lead(40, 0.2, 2.0) == pytest.approx(timing.LEAD_MS[-1][row][column] / 1000)
    assert timing.lead(-40, 0.2, 9.0) == timing.lead(40, 0.2, 2.0)  # beyond 2 s: as at 2 s
    assert timing.lead(200, 5.0, 0.1) == pytest.approx(timing.LEAD_MS[0][-1][-1] / 1000)
    mid = timing.lead(45, 0.2, 2.0)
    assert min(timing.lead(40, 0.2, 2.0), timing.lead(50, 0.2, 2.0)) <= mid <= max(
        timing.lead(40, 0.2, 2.0), timing.lead(50, 0.2, 2.0))
    # hwbridge's profile needs T' > 2A, whatever the lead.
    assert timing.timed_duration(94, 94, 0.41, 0.2, unit=UNIT, max_speed=0.5, max_accel=2.0) > 0.4


def test_another_motor_runs_on_differently() -> None:
    """The lead is the motor's: it runs on after the stop for its time constant. On a motor with
    0.15 s instead of the report's 0.1 s, 40 units for 1 s go ~4 % further than the table expects
    (docs/webapi.md: on a robot, calibrate with timed drives of the lengths you use)."""
    slow = statistics.mean(error(40, 1.0, 0.0, motor=Motor(tau=0.15), phases=PHASES))
    assert slow > 0.02, slow
