"""SLAM's state between bus messages: the localizer's bookkeeping (odometry increments, late
frames brought up to date, bad input logged once a second) around `EkfSlam` instead of `Ekf`.
No bus here: `__main__.py` feeds it ``odom/pose`` and ``camera/landmarks``; tests and the
benchmark feed it the same messages built in-process.
"""

from __future__ import annotations

import logging

from icefloe.config import RobotConfig
from icefloe.estimation.ekf import Noise
from icefloe.estimation.landmarks import landmark_map, plausible
from icefloe.estimation.localizer import Localizer
from icefloe.schemas import messages as m

from .ekfslam import EkfSlam


class Slam(Localizer):
    """The localizer's tracker with a filter that maps as it goes (and never relocalizes)."""

    def __init__(self, config: RobotConfig, log: logging.Logger) -> None:
        super().__init__(config, log)  # reads [localizer]'s world only to check it; SLAM ignores it
        c = config.localizer
        noise = Noise(c.sigma_range, c.sigma_range_rel, c.sigma_bearing,
                      c.odom_sigma_d, c.odom_sigma_theta, c.odom_sigma_theta_d)
        self.ekf = EkfSlam(noise, gate_chi2=config.slam.gate_chi2,  # type: ignore[assignment]
                           max_landmarks=config.slam.max_landmarks)
        self.initialised = True  # SLAM's frame is where the robot starts
        self._relocalize_after = 0

    def estimate(self) -> m.PoseEstimate:
        x, y, th = self.ekf.pose
        return m.PoseEstimate(stamp=self.stamp, x=x, y=y, theta=th,
                              covariance=[float(v) for v in self.ekf.pose_covariance.ravel()])

    def on_landmarks(self, frame: m.Landmarks) -> bool:
        good = plausible(frame, self._warn)
        return super().on_landmarks(frame if len(good) == len(frame.landmarks) else
                                    m.Landmarks(stamp=frame.stamp, landmarks=good))

    def landmark_map(self) -> m.LandmarkMap:
        return landmark_map(self.ekf, self.stamp)
