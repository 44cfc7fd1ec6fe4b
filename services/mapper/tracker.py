"""The map maker's state between bus messages: known poses kept for a second, each camera frame
matched with the pose at its stamp, bad input logged once a second. No bus here."""

from __future__ import annotations

import logging
from collections import deque

from icefloe.angles import wrap_angle
from icefloe.config import RobotConfig
from icefloe.estimation.ekf import Noise, Outcome
from icefloe.estimation.landmarks import landmark_map, plausible
from icefloe.logs import LimitedLog
from icefloe.schemas import messages as m

from .mapping import LandmarkMapper

HISTORY_NS = 1_000_000_000
"""How long known poses are kept to match late camera frames, ns."""
MAX_GAP_NS = 200_000_000
"""A frame further than this from any known pose is not used (the pose source stalled), ns."""


class Mapper:
    def __init__(self, config: RobotConfig, log: logging.Logger) -> None:
        c, mc = config.localizer, config.mapper
        noise = Noise(c.sigma_range, c.sigma_range_rel, c.sigma_bearing)
        self.mapper = LandmarkMapper(
            noise, pose_sigma=(mc.pose_sigma_xy, mc.pose_sigma_xy, mc.pose_sigma_theta),
            gate_chi2=mc.gate_chi2, max_landmarks=mc.max_landmarks)
        self.log = log
        self._warn = LimitedLog(log, burst=1)
        self._poses: deque[tuple[int, float, float, float]] = deque()
        self.stamp = 0
        self.unmatched_frames = 0

    def on_pose(self, pose: m.ExternalPose | m.Truth) -> None:
        if self._poses and pose.stamp <= self._poses[-1][0]:
            self._poses.clear()  # time went backwards (the pose source restarted): start over
        self._poses.append((pose.stamp, pose.x, pose.y, pose.theta))
        while self._poses[0][0] < pose.stamp - HISTORY_NS:
            self._poses.popleft()

    def pose_at(self, stamp: int) -> tuple[float, float, float] | None:
        """The known pose at ``stamp``, interpolated; None if no pose is near enough."""
        poses = self._poses
        if not poses or not poses[0][0] - MAX_GAP_NS <= stamp <= poses[-1][0] + MAX_GAP_NS:
            return None
        prev = poses[0]
        for cur in poses:
            if cur[0] >= stamp:
                t0, x0, y0, th0 = prev
                t1, x1, y1, th1 = cur
                if t1 - t0 > MAX_GAP_NS:
                    return None
                f = min(max((stamp - t0) / (t1 - t0), 0.0), 1.0) if t1 > t0 else 1.0
                return x0 + f * (x1 - x0), y0 + f * (y1 - y0), wrap_angle(th0 + f * wrap_angle(th1 - th0))
            prev = cur
        return poses[-1][1:]

    def on_landmarks(self, frame: m.Landmarks) -> bool:
        """Add a frame's sightings; True if the map changed."""
        pose = self.pose_at(frame.stamp)
        if pose is None:
            self.unmatched_frames += 1
            self._warn.warning("camera/landmarks without pose",
                               f"camera/landmarks frame at {frame.stamp} has no known pose within "
                               f"{MAX_GAP_NS / 1e6:.0f} ms (is the pose source running?): not used; "
                               f"{self.unmatched_frames} so far")
            return False
        changed = False
        for lm in plausible(frame, self._warn):
            result = self.mapper.observe(pose, lm.id, lm.range, lm.bearing)
            if result.outcome is Outcome.ACCEPTED:
                changed = True
            elif result.outcome is Outcome.OUTLIER:
                self._warn.warning("landmark outlier",
                                   f"landmark {lm.id} at range {lm.range:.3f} m, bearing {lm.bearing:.3f} rad "
                                   f"rejected by the gate (d2={result.d2:.1f}); {self.mapper.outliers} so far")
            else:
                self._warn.warning("map full", f"landmark {lm.id}: the map already holds "
                                   f"{self.mapper.max_landmarks} landmarks (mapper.max_landmarks): not added")
        self.stamp = max(self.stamp, frame.stamp)
        return changed

    def landmark_map(self) -> m.LandmarkMap:
        return landmark_map(self.mapper, self.stamp)


