"""Unit tests of the pure EKF (icefloe/estimation/ekf.py)."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from icefloe.angles import wrap_angle
from icefloe.estimation.ekf import Ekf, Noise, Outcome, increment, pose_from_landmarks, shift_sighting
from icefloe.worldmap import load_world

LAB = {m.id: (m.x, m.y) for m in load_world("lab").markers}


def observe_from(pose: tuple[float, float, float], lid: int) -> tuple[float, float]:
    """Exact (range, bearing) of landmark ``lid`` from ``pose``."""
    mx, my = LAB[lid]
    x, y, th = pose
    return math.hypot(mx - x, my - y), wrap_angle(math.atan2(my - y, mx - x) - th)


def test_increment_is_frame_independent() -> None:
    # The same motion seen from two odometry frames rotated and shifted against each other.
    a0, a1 = (0.0, 0.0, 0.0), (0.1, 0.02, 0.3)
    c, s = math.cos(2.0), math.sin(2.0)

    def move(p: tuple[float, float, float]) -> tuple[float, float, float]:
        return 5 + c * p[0] - s * p[1], -3 + s * p[0] + c * p[1], wrap_angle(p[2] + 2.0)

    assert increment(a0, a1) == pytest.approx((0.1, 0.02, 0.3))
    assert increment(move(a0), move(a1)) == pytest.approx((0.1, 0.02, 0.3))
    assert increment((0, 0, 3.0), (0, 0, -3.0))[2] == pytest.approx(2 * math.pi - 6.0)


def test_predict_moves_the_mean_and_grows_the_covariance() -> None:
    ekf = Ekf(LAB, mean=(1.0, 1.0, math.pi / 2), sigma=(0.01, 0.01, 0.01))
    p0 = ekf.P.copy()
    for _ in range(100):
        ekf.predict(0.01, 0.0, 0.0)
    assert ekf.pose == pytest.approx((1.0, 2.0, math.pi / 2))
    assert np.trace(ekf.P) > np.trace(p0)
    assert ekf.P[0, 0] > p0[0, 0]  # heading uncertainty spreads sideways (x, when facing +y)
    assert np.allclose(ekf.P, ekf.P.T)


def test_converges_from_a_wrong_initial_pose() -> None:
    truth = (0.3, -0.4, 0.5)
    rng = random.Random(1)
    ekf = Ekf(LAB, mean=(0.0, 0.0, 0.2), sigma=(0.5, 0.5, 0.4))
    before = math.hypot(ekf.pose[0] - truth[0], ekf.pose[1] - truth[1])
    for _ in range(30):  # 30 frames of the markers ahead (east and north walls)
        for lid in (0, 1, 2, 5):
            r, b = observe_from(truth, lid)
            result = ekf.observe(lid, r + rng.gauss(0, 0.02), b + rng.gauss(0, 0.01))
            assert result.outcome is Outcome.ACCEPTED
    x, y, th = ekf.pose
    assert before > 0.4
    assert math.hypot(x - truth[0], y - truth[1]) < 0.03
    assert abs(wrap_angle(th - truth[2])) < math.radians(1.5)
    assert ekf.P[0, 0] < 0.03**2 and ekf.P[2, 2] < math.radians(2) ** 2


def test_gate_rejects_an_outlier_and_keeps_the_pose() -> None:
    truth = (0.0, 0.0, 0.0)
    ekf = Ekf(LAB, mean=truth, sigma=(0.02, 0.02, 0.02))
    r, b = observe_from(truth, 1)
    assert ekf.observe(1, r, b).outcome is Outcome.ACCEPTED
    mu, P = ekf.mu.copy(), ekf.P.copy()
    bad = ekf.observe(1, r + 0.8, b)  # a reflection, a misread id: 0.8 m off
    assert bad.outcome is Outcome.OUTLIER and bad.d2 > ekf.gate_chi2
    bad = ekf.observe(1, r, b + 0.5)
    assert bad.outcome is Outcome.OUTLIER
    assert np.array_equal(ekf.mu, mu) and np.array_equal(ekf.P, P)
    assert (ekf.accepted, ekf.outliers) == (1, 2)


def test_unknown_ids_are_counted_and_ignored() -> None:
    ekf = Ekf(LAB)
    mu = ekf.mu.copy()
    assert ekf.observe(42, 1.0, 0.0).outcome is Outcome.UNKNOWN
    assert ekf.observe(43, 1.0, 0.0).outcome is Outcome.UNKNOWN
    assert ekf.unknown == 2 and ekf.accepted == 0
    assert np.array_equal(ekf.mu, mu)


def test_bearing_innovation_wraps_at_pi() -> None:
    # Facing east, a landmark due west is at bearing ~pi; a sighting at -pi + 0.01 is 0.01 rad off, not 2 pi.
    ekf = Ekf(LAB, mean=(0.0, 0.0, 0.0), sigma=(0.02, 0.02, 0.02))
    r, b = observe_from((0.0, 0.0, 0.0), 7)
    assert abs(b) == pytest.approx(math.pi)
    assert ekf.observe(7, r, -math.pi + 0.01).outcome is Outcome.ACCEPTED
    assert -math.pi < ekf.pose[2] <= math.pi and abs(wrap_angle(ekf.pose[2])) < 0.02


def test_pose_from_two_or_more_landmarks() -> None:
    truth = (-0.7, 0.4, 2.5)
    seen = [(LAB[i], *observe_from(truth, i)) for i in (3, 4, 8)]
    assert pose_from_landmarks(seen) == pytest.approx(truth, abs=1e-9)
    assert pose_from_landmarks(seen[:2]) == pytest.approx(truth, abs=1e-9)
    assert pose_from_landmarks(seen[:1]) is None


def test_noise_from_config_reaches_the_filter() -> None:
    tight = Ekf(LAB, Noise(sigma_range=0.001, sigma_range_rel=0.0, sigma_bearing=0.001),
                sigma=(0.001, 0.001, 0.001))
    r, b = observe_from((0.0, 0.0, 0.0), 1)
    assert tight.observe(1, r + 0.05, b).outcome is Outcome.OUTLIER
    loose = Ekf(LAB, Noise(sigma_range=0.1), sigma=(0.001, 0.001, 0.001))
    assert loose.observe(1, r + 0.05, b).outcome is Outcome.ACCEPTED


def test_shift_sighting_matches_seeing_it_from_the_new_pose() -> None:
    then, now = (0.2, -0.3, 0.4), (0.28, -0.25, 0.65)
    u = increment(then, now)
    for lid in (0, 1, 2, 5):
        r, b = observe_from(then, lid)
        assert shift_sighting(r, b, u) == pytest.approx(observe_from(now, lid), abs=1e-12)


def _config(**localizer: float):
    import msgspec

    from icefloe.config import load

    base = load()
    return msgspec.structs.replace(base, localizer=msgspec.structs.replace(base.localizer, **localizer))


def test_late_frames_are_brought_up_to_date_with_odometry() -> None:
    """Turning on the spot at 1.5 rad/s; each frame arrives 80 ms after it was taken."""
    import logging

    from icefloe.estimation.localizer import Localizer
    from icefloe.schemas import messages as m

    loc = Localizer(_config(initial_sigma_xy=0.01, initial_sigma_theta=0.01), logging.getLogger("test"))
    t0, rate = 1_000_000_000_000, 1.5
    poses = []  # the robot's true pose = odometry pose here (perfect odometry)
    worst = 0.0
    for k in range(150):  # 3 s, odometry at 50 Hz
        stamp = t0 + k * 20_000_000
        theta = wrap_angle(rate * k * 0.02)
        poses.append((stamp, theta))
        loc.on_odometry(m.Pose(stamp=stamp, x=0.0, y=0.0, theta=theta))
        if k >= 4 and k % 3 == 0:
            s_then, th_then = poses[k - 4]  # taken 80 ms ago
            frame = [m.Landmark(id=i, range=r, bearing=b) for i in LAB
                     for r, b in [observe_from((0.0, 0.0, th_then), i)] if abs(b) < 0.6]
            loc.on_landmarks(m.Landmarks(stamp=s_then, landmarks=frame))
            worst = max(worst, abs(wrap_angle(loc.ekf.pose[2] - theta)))
    assert loc.ekf.accepted > 100 and loc.ekf.outliers == 0
    assert worst < math.radians(0.5)
    assert loc.estimate().stamp == poses[-1][0]
    # A frame older than the odometry kept is stale: counted, not used.
    before = loc.ekf.accepted
    loc.on_landmarks(m.Landmarks(stamp=t0, landmarks=[m.Landmark(id=1, range=2.0, bearing=0.0)]))
    assert loc.stale_frames == 1 and loc.ekf.accepted == before


def test_frames_newer_than_the_odometry_are_moved_back_along_its_speeds() -> None:
    """Turning on the spot at 1.5 rad/s; each frame is taken 15 ms after the latest odometry pose."""
    import logging

    from icefloe.estimation.localizer import Localizer
    from icefloe.schemas import messages as m

    loc = Localizer(_config(initial_sigma_xy=0.01, initial_sigma_theta=0.01), logging.getLogger("test"))
    t0, rate, ahead = 1_000_000_000_000, 1.5, 15_000_000
    worst = 0.0
    for k in range(150):  # 3 s, odometry at 50 Hz with its speed estimate
        stamp = t0 + k * 20_000_000
        theta = wrap_angle(rate * k * 0.02)
        loc.on_odometry(m.Pose(stamp=stamp, x=0.0, y=0.0, theta=theta, v=0.0, w=rate))
        if k >= 1 and k % 3 == 0:
            th_frame = wrap_angle(theta + rate * ahead * 1e-9)  # 1.3 degrees further round
            frame = [m.Landmark(id=i, range=r, bearing=b) for i in LAB
                     for r, b in [observe_from((0.0, 0.0, th_frame), i)] if abs(b) < 0.6]
            loc.on_landmarks(m.Landmarks(stamp=stamp + ahead, landmarks=frame))
            worst = max(worst, abs(wrap_angle(loc.ekf.pose[2] - theta)))
    assert loc.ekf.accepted > 100 and loc.ekf.outliers == 0
    assert worst < math.radians(0.2)  # taken as if at the odometry's time it would be ~1.3 degrees


def test_initial_pose_from_the_first_frame_with_two_landmarks() -> None:
    import logging

    from icefloe.estimation.localizer import Localizer
    from icefloe.schemas import messages as m

    loc = Localizer(_config(init="landmarks", initial_x=9.0), logging.getLogger("test"))
    truth = (0.4, 0.3, 1.2)
    one = [m.Landmark(id=4, range=r, bearing=b) for r, b in [observe_from(truth, 4)]]
    assert loc.on_landmarks(m.Landmarks(stamp=1, landmarks=one)) is False  # one marker cannot fix a pose
    assert not loc.initialised
    two = [*one, *(m.Landmark(id=i, range=r, bearing=b) for i in (3, 5) for r, b in [observe_from(truth, i)])]
    assert loc.on_landmarks(m.Landmarks(stamp=2, landmarks=two)) is True
    assert loc.initialised
    assert loc.ekf.pose == pytest.approx(truth, abs=1e-6)
    assert loc.estimate().stamp == 2


def test_kidnapped_robot_is_found_again() -> None:
    import logging

    from icefloe.estimation.localizer import Localizer
    from icefloe.schemas import messages as m

    loc = Localizer(_config(initial_sigma_xy=0.01, initial_sigma_theta=0.01, relocalize_after=10),
                    logging.getLogger("test"))
    carried_to = (0.8, -0.5, 2.0)  # picked up at the origin and put down here
    frame = m.Landmarks(stamp=1, landmarks=[m.Landmark(id=i, range=r, bearing=b)
                                            for i in (6, 7, 8) for r, b in [observe_from(carried_to, i)]])
    for _ in range(3):  # 9 sightings: gated out, still lost
        loc.on_landmarks(frame)
    assert loc.relocalized == 0 and loc.ekf.outliers == 9
    loc.on_landmarks(frame)  # the 10th fails, then ...
    loc.on_landmarks(frame)  # ... the next frame restarts the filter
    assert loc.relocalized == 1
    assert loc.ekf.pose == pytest.approx(carried_to, abs=1e-6)
    assert loc.ekf.accepted == 3
