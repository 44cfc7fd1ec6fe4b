"""The map maker's and the EKF-SLAM's maths alone (services/mapper/mapping.py, services/slam/ekfslam.py),
on a seeded tour of the lab: the camera model of the localizer's harness, odometry with drift. ~2 s."""

from __future__ import annotations

import itertools
import logging
import math
import random

import numpy as np
import pytest

from icefloe.angles import wrap_angle
from icefloe.config import RobotConfig
from icefloe.estimation.ekf import Noise, Outcome
from icefloe.schemas import messages as m
from icefloe.score.maths import score_map
from icefloe.services.mapper.mapping import LandmarkMapper
from icefloe.services.mapper.tracker import Mapper
from icefloe.services.slam.ekfslam import EkfSlam
from icefloe.services.slam.tracker import Slam
from icefloe.testing import TruthCamera
from icefloe.worldmap import load_world

TRUE = {mk.id: (mk.x, mk.y) for mk in load_world("lab").markers}
NOISE = Noise(sigma_range=0.02, sigma_range_rel=0.01, sigma_bearing=0.01)


def tour(seconds: float = 120.0, dt: float = 0.02):
    """True poses around a 1 m square with rounded corners, at 0.2 m/s: (t, x, y, theta) every dt."""
    x = y = th = 0.0
    t = 0.0
    out = [(t, x, y, th)]
    legs = [(0.2, 0.0, 5.0), (0.0, 1.5, math.pi / 2 / 1.5)] * 100
    for v, w, dur in legs:
        for _ in range(round(dur / dt)):
            th = wrap_angle(th + w * dt)
            x, y = x + v * dt * math.cos(th), y + v * dt * math.sin(th)
            t += dt
            out.append((t, x, y, th))
            if t >= seconds:
                return out
    return out


def camera(seed: int) -> TruthCamera:
    return TruthCamera(RobotConfig(), random.Random(seed), sigma_range=0.02, sigma_range_rel=0.01, sigma_bearing=0.01)


def test_the_map_maker_maps_the_lab_from_true_poses_within_5_cm() -> None:
    cam = camera(1)
    mapper = LandmarkMapper(NOISE)
    for k, (_, x, y, th) in enumerate(tour(60)):
        if k % 4 == 0:
            for lm in cam.frame((x, y, th), 0).landmarks:
                mapper.observe((x, y, th), lm.id, lm.range, lm.bearing)
    score = score_map(mapper.landmarks, TRUE)
    print(f"\nmap maker: {len(mapper.landmarks)} landmarks, RMSE {score.rmse * 100:.2f} cm "
          f"(raw {score.rmse_raw * 100:.2f} cm)")
    assert len(mapper.landmarks) >= 8 and score.rmse < 0.05 and score.rmse_raw < 0.05
    for i in mapper.landmarks:  # the covariance says how sure it is: small, symmetric, positive
        c = mapper.covariance(i)
        assert np.allclose(c, c.T) and np.all(np.linalg.eigvalsh(c) > 0) and math.sqrt(c.trace()) < 0.05


def test_ekf_slam_maps_the_lab_and_tracks_the_robot_with_drifting_odometry() -> None:
    cam = camera(2)
    slam = EkfSlam(NOISE)
    odom_rng = random.Random(3)
    poses = tour(120)
    for k, ((_, *a), (_, *b)) in enumerate(itertools.pairwise(poses)):
        c, s = math.cos(a[2]), math.sin(a[2])
        ex, ey = b[0] - a[0], b[1] - a[1]
        dx, dy, dth = c * ex + s * ey, -s * ex + c * ey, wrap_angle(b[2] - a[2])
        # odometry: 2 % scale error and a slow heading drift, plus noise
        slam.predict(dx * 1.02, dy, dth * 1.01 + 0.002 * abs(dx) + odom_rng.gauss(0, 0.0005))
        if k % 4 == 0:
            for lm in cam.frame(tuple(b), 0).landmarks:
                slam.observe(lm.id, lm.range, lm.bearing)
    score = score_map(slam.landmarks, TRUE)
    x, y, th = slam.pose
    (ex, ey), = score.alignment.apply(np.array([[x, y]]))
    final = poses[-1]
    pos_err = math.hypot(ex - final[1], ey - final[2])
    head_err = abs(wrap_angle(th + score.alignment.rotation - final[3]))
    print(f"\nEKF-SLAM: {len(slam.landmarks)} landmarks, map RMSE {score.rmse * 100:.2f} cm, final pose "
          f"{pos_err * 100:.2f} cm {math.degrees(head_err):.2f} deg")
    assert len(slam.landmarks) >= 8 and score.rmse < 0.05
    assert pos_err < 0.05 and head_err < math.radians(3)
    P = slam.P
    assert np.allclose(P, P.T, atol=1e-12) and np.all(np.linalg.eigvalsh(P) > -1e-12)


def test_a_new_landmark_is_correlated_with_the_robot_and_the_map_is_bounded() -> None:
    slam = EkfSlam(NOISE, max_landmarks=3, sigma=(0.1, 0.1, 0.1))
    assert slam.observe(7, 1.0, 0.0).outcome is Outcome.ACCEPTED
    assert slam.landmarks == {7: pytest.approx((1.0, 0.0))}
    assert abs(slam.P[0, 3]) > 0  # where the robot is uncertain, so is what it saw
    for i in range(100):
        slam.observe(100 + i, 1.0, 0.5)
    assert len(slam.landmarks) == 3 and slam.P.shape == (9, 9) and slam.unknown == 98
    # a gross error fails the gate and leaves the estimate alone
    before = slam.mu.copy()
    assert slam.observe(7, 3.0, 1.0).outcome is Outcome.OUTLIER
    assert np.array_equal(before, slam.mu)


def test_trackers_refuse_implausible_sightings_with_one_line(caplog) -> None:
    log = logging.getLogger("test.slam")
    slam, mapper = Slam(RobotConfig(), log), Mapper(RobotConfig(), log)
    mapper.on_pose(m.Truth(stamp=1_000, x=0.0, y=0.0, theta=0.0))
    bad = m.Landmarks(stamp=1_000, landmarks=[m.Landmark(id=1, range=-1.0, bearing=0.0),
                                              m.Landmark(id=2, range=1.0, bearing=7.0),
                                              m.Landmark(id=3, range=1.0, bearing=0.1)])
    with caplog.at_level(logging.WARNING, "test.slam"):
        for _ in range(50):
            slam.on_landmarks(bad)
            mapper.on_landmarks(bad)
    assert set(slam.ekf.landmarks) == {3} and set(mapper.mapper.landmarks) == {3}
    lines = [r for r in caplog.records if "not a sighting" in r.getMessage()]
    assert 1 <= len(lines) <= 2 and "landmark 1 at range -1.0 m" in lines[0].getMessage()
    # a frame with no known pose near it is not used
    assert not mapper.on_landmarks(m.Landmarks(stamp=10**12, landmarks=[m.Landmark(id=4, range=1.0, bearing=0.0)]))
    assert 4 not in mapper.mapper.landmarks
