"""Odometry's and the localizer's poses at rest (issue 35), pure: `icefloe.heartbeat` with an injected
clock, and the localizer's state fed odometry's heartbeat of a still robot."""

from __future__ import annotations

import itertools
import logging
import random

import pytest
from test_localizer_ekf import LAB, _config, observe_from

from icefloe.estimation.localizer import HISTORY_NS, Localizer
from icefloe.heartbeat import Heartbeat
from icefloe.schemas import messages as m


def published(beat: Heartbeat, changes: list[bool], dt: float) -> list[float]:
    """The times a stream ticking every ``dt`` s publishes, ``changes[i]``: whether tick i changed something."""
    return [i * dt for i, changed in enumerate(changes) if beat.due(changed, i * dt)]


def test_a_change_is_published_at_once_and_nothing_changing_at_the_heartbeat_rate() -> None:
    beat = Heartbeat(0.25, slack_s=0.01)
    # 1 s moving at 50 Hz, then 2 s standing: every tick, then one each 0.25 s
    times = published(beat, [True] * 50 + [False] * 100, 0.02)
    assert len([t for t in times if t < 1.0]) == 50
    standing = [t for t in times if t >= 1.0]
    assert len(standing) == beat.beats == 8  # every 0.24 or 0.26 s: the first tick within half a tick of 0.25 s
    assert all(0.24 - 1e-9 <= b - a <= 0.26 + 1e-9 for a, b in itertools.pairwise(standing))
    assert beat.due(True, 3.0)  # a change after the rest: at once, whenever the last beat was


def test_a_heartbeat_as_fast_as_its_loop_publishes_every_tick_though_the_ticks_jitter() -> None:
    """rest_rate_hz = rate_hz (bench/lab_harness.py's robots): a pose every period standing too, as before.
    Without the slack, a tick 1 ms early was passed over: 15 of 25 a second in tests/test_lab.py."""
    beat = Heartbeat(0.04, slack_s=0.02)
    rng = random.Random(3)
    ticks = [i * 0.04 + rng.uniform(-0.005, 0.005) for i in range(100)]
    assert all(beat.due(False, t) for t in ticks)


def test_the_first_tick_is_published_whatever_changed() -> None:
    assert Heartbeat(10.0).due(False, 123.0)


def test_odometrys_heartbeat_of_a_still_robot_keeps_the_localizer_still_and_its_history_short() -> None:
    """A still robot: odometry repeats one pose, each time with a new sample's stamp or with none new;
    the estimate does not change (no publication due but the heartbeat), and a pose repeated with its
    stamp is not kept twice (a robot standing for an hour would grow the history by 14 400 poses)."""
    loc = Localizer(_config(initial_sigma_xy=0.01, initial_sigma_theta=0.01), logging.getLogger("test"))
    t0 = 1_000_000_000_000
    loc.on_odometry(m.Pose(stamp=t0, x=0.1, y=0.0, theta=0.0))
    before = loc.changes
    for k in range(1, 400):  # 100 s at 4 Hz, a new sample only every other heartbeat
        stamp = t0 + (k // 2) * 500_000_000
        loc.on_odometry(m.Pose(stamp=stamp, x=0.1, y=0.0, theta=0.0))
    assert loc.changes == before, "a still robot's odometry changed the estimate"
    assert len(loc._history) <= HISTORY_NS // 500_000_000 + 2
    # a frame at rest (the camera's 1 Hz) updates it: published at once
    frame = [m.Landmark(id=i, range=r, bearing=b) for i in LAB for r, b in [observe_from((0.0, 0.0, 0.0), i)]
             if abs(b) < 0.6]
    assert loc.on_landmarks(m.Landmarks(stamp=t0 + 199 * 500_000_000, landmarks=frame))
    assert loc.changes == before + 1
    # moving again: each pose changes it
    loc.on_odometry(m.Pose(stamp=t0 + 200 * 500_000_000, x=0.11, y=0.0, theta=0.0))
    assert loc.changes == before + 2
    assert loc.estimate().stamp == t0 + 200 * 500_000_000


def test_odometry_reset_with_the_same_stamp_is_still_seen() -> None:
    """odom/reset answers with the pose at the latest sample's stamp: not a heartbeat repeat, a jump."""
    loc = Localizer(_config(), logging.getLogger("test"))
    loc.on_odometry(m.Pose(stamp=10, x=1.0, y=0.0, theta=0.0))
    loc.on_odometry(m.Pose(stamp=10, x=0.0, y=0.0, theta=0.0))
    assert loc.skipped_odometry == 1


@pytest.mark.parametrize("rate", [4.0, 50.0])
def test_the_rest_rates_are_config_keys(rate: float) -> None:
    cfg = _config(rest_rate_hz=rate)
    assert cfg.localizer.rest_rate_hz == rate and cfg.odometry.rest_rate_hz == 4.0
