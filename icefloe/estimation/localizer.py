"""The localizer's state between bus messages: the EKF plus input checks, initialisation and logging.

No bus here: `__main__.py` feeds it `odom/pose` and `camera/landmarks` messages,
the simulation harness (`simrun.py`) feeds it the same messages built in-process.
"""

from __future__ import annotations

import logging
import math
from collections import deque

from ..angles import wrap_angle
from ..config import RobotConfig
from ..logs import LimitedLog
from ..schemas import messages as m
from ..vision.geometry import Mount
from ..worldmap import load_world
from .blocks import to_centres
from .ekf import Ekf, Noise, Outcome, increment, pose_from_landmarks, shift_sighting


def make_ekf(config: RobotConfig) -> Ekf:
    """The filter configured from the robot config (whose values were checked when it was read) and
    its world map; `ConfigError` naming the world file if that is bad."""
    c = config.localizer
    world = load_world(c.world)
    noise = Noise(c.sigma_range, c.sigma_range_rel, c.sigma_bearing,
                  c.odom_sigma_d, c.odom_sigma_theta, c.odom_sigma_theta_d)
    return Ekf(world.landmarks(), noise, gate_chi2=c.gate_chi2,
               mean=(c.initial_x, c.initial_y, c.initial_theta),
               sigma=(c.initial_sigma_xy, c.initial_sigma_xy, c.initial_sigma_theta))


HISTORY_NS = 1_000_000_000
"""How long odometry poses are kept to bring late landmark frames up to date, ns."""
EXTRAPOLATE_S = 0.1
"""A frame up to this much newer than the latest odometry is moved back along the odometry's speeds."""


class Localizer:
    """The service's state: the filter plus the bookkeeping between bus messages (no bus here).

    Timing: the filter's estimate is for the time of the latest odometry pose
    (`stamp`). A camera frame is older than that (exposure, detection, the
    bus); its sightings are moved to the present with the odometry increment
    since the frame's stamp (`shift_sighting`) before the update. Frames older
    than the odometry kept (`HISTORY_NS`) are dropped as stale. A frame newer
    than the latest odometry (a camera faster than the 50 Hz poses) is moved
    back by the motion the odometry's speeds predict (`EXTRAPOLATE_S` at most).

    Lost: when ``localizer.relocalize_after`` sightings in a row fail the gate
    (the robot was carried away, the start pose was wrong beyond its sigma),
    the next frame with two or more known markers restarts the filter there.
    """

    def __init__(self, config: RobotConfig, log: logging.Logger) -> None:
        self.ekf = make_ekf(config)
        self._half_sides = {b.id: b.side / 2 for b in load_world(config.localizer.world).blocks}
        """Marker blocks: a sighting of a face is moved to the cube's centre (`blocks`)."""
        self._mount = Mount.from_config(config.camera)
        self.log = log
        self._warn = LimitedLog(log, burst=1)
        """One line per second per kind of event (and how many more happened)."""
        self.initialised = config.localizer.init == "config"
        self._sigma0 = (config.localizer.initial_sigma_xy,) * 2 + (config.localizer.initial_sigma_theta,)
        self._max_speed = config.odometry.max_wheel_speed
        self._margin = config.odometry.jump_margin
        self._track = config.geometry.track
        self._last_odom: m.Pose | None = None
        self._history: deque[tuple[int, float, float, float]] = deque()  # (stamp ns, x, y, theta) odometry
        self.stamp = 0
        """ns: the time the estimate is for (latest odometry, or the latest frame before any odometry)."""
        self.stale_frames = 0
        self.relocalized = 0
        self._relocalize_after = config.localizer.relocalize_after
        self._rejected_in_a_row = 0
        self.skipped_odometry = 0
        self.changes = 0
        """Times the estimate changed (odometry moved it, a frame updated it): the service publishes a
        change at once, and only a heartbeat while this stays the same."""

    def on_odometry(self, pose: m.Pose) -> None:
        prev = self._last_odom
        if prev is not None and pose == prev:
            return  # odometry's heartbeat with no new wheel sample: nothing new, and nothing to keep
        self._last_odom = pose
        if prev is None:
            self._history.append((pose.stamp, pose.x, pose.y, pose.theta))
            return
        dt = (pose.stamp - prev.stamp) * 1e-9
        dx, dy, dth = increment((prev.x, prev.y, prev.theta), (pose.x, pose.y, pose.theta))
        # Limits: the faster wheel bounds both the travel of the centre and the turn (|dth| <= 2 v dt / b).
        reach = self._max_speed * max(dt, 0.0) + self._margin
        if dt < 0 or math.hypot(dx, dy) > reach or abs(dth) * self._track / 2 > reach:
            self.skipped_odometry += 1
            self._warn.warning(
                "odom/pose jump",
                f"odom/pose jumped by ({dx:.3f} m, {dy:.3f} m, {dth:.3f} rad) in {dt:.3f} s "
                "(odometry reset or restarted?): not used as motion")
            self._history.clear()  # the odometry frame changed: older poses are in another frame
            self._history.append((pose.stamp, pose.x, pose.y, pose.theta))
            return
        self._history.append((pose.stamp, pose.x, pose.y, pose.theta))
        while self._history[0][0] < pose.stamp - HISTORY_NS:
            self._history.popleft()
        if self.initialised:
            if dx or dy or dth:
                self.ekf.predict(dx, dy, dth)
                self.changes += 1
            self.stamp = pose.stamp

    def _odometry_at(self, stamp: int) -> tuple[float, float, float] | None:
        """The odometry pose at ``stamp`` (linear interpolation), None if older than the history kept."""
        hist = self._history
        if not hist or stamp < hist[0][0]:
            return None
        for (t0, x0, y0, th0), (t1, x1, y1, th1) in zip(hist, list(hist)[1:], strict=False):
            if t0 <= stamp <= t1:
                f = (stamp - t0) / (t1 - t0) if t1 > t0 else 1.0
                return x0 + f * (x1 - x0), y0 + f * (y1 - y0), wrap_angle(th0 + f * wrap_angle(th1 - th0))
        # Newer than the latest odometry (a fast camera, odometry published every 20 ms): carry the
        # latest pose on at its measured speeds, for a short while only.
        t, x, y, th = hist[-1]
        ahead = (stamp - t) * 1e-9
        last = self._last_odom
        if last is None or ahead > EXTRAPOLATE_S:
            return x, y, th
        mid = th + last.w * ahead / 2  # the heading halfway: exact enough for a few ms
        return x + last.v * ahead * math.cos(mid), y + last.v * ahead * math.sin(mid), wrap_angle(th + last.w * ahead)

    def on_landmarks(self, frame: m.Landmarks) -> bool:
        """Apply a frame; True if the estimate exists afterwards (so it is worth publishing)."""
        u = (0.0, 0.0, 0.0)  # the robot's motion since the frame was taken (robot frame then)
        if self._history:
            then = self._odometry_at(frame.stamp)
            if then is None:
                self.stale_frames += 1
                self._warn.warning(
                    "camera/landmarks stale",
                    f"camera/landmarks frame {(self._history[-1][0] - frame.stamp) * 1e-9:.3f} s older than "
                    f"the odometry: stale, not used; {self.stale_frames} so far")
                return self.initialised
            u = increment(then, self._history[-1][1:])
        seen = to_centres(frame.landmarks, self._half_sides, self._mount)  # one sighting per block
        sightings = [(lm.id, *shift_sighting(lm.range, lm.bearing, u)) for lm in seen]
        lost = 0 < self._relocalize_after <= self._rejected_in_a_row
        if not self.initialised or lost:
            known = [(self.ekf.landmarks[i], r, b) for i, r, b in sightings if i in self.ekf.landmarks]
            pose = pose_from_landmarks(known)
            if pose is None:
                return self.initialised
            self.ekf.set_pose(pose, self._sigma0)
            if lost:
                self.relocalized += 1
                self._rejected_in_a_row = 0
                self._warn.warning("relocalized", "lost (%d sightings in a row failed the gate): restarted "
                                   "from %d landmarks at x=%.3f y=%.3f theta=%.3f",
                                   self._relocalize_after, len(known), *pose)
            else:
                self.log.info("initial pose from %d landmarks: x=%.3f y=%.3f theta=%.3f", len(known), *pose)
            self.initialised = True
        for lid, rng, bearing in sightings:
            result = self.ekf.observe(lid, rng, bearing)
            if result.outcome is Outcome.ACCEPTED:
                self._rejected_in_a_row = 0
            elif result.outcome is Outcome.OUTLIER:
                self._rejected_in_a_row += 1
                self._warn.warning(
                    "landmark outlier",
                    f"landmark {lid} at range {rng:.3f} m, bearing {bearing:.3f} rad "
                    f"{result.outcome.value} (d2={result.d2:.1f} > {self.ekf.gate_chi2}); "
                    f"{self.ekf.outliers} outliers so far")
            else:
                self._warn.warning(
                    "landmark unknown",
                    f"landmark {lid}: {result.outcome.value}; {self.ekf.unknown} unknown sightings so far")
        if not self._history:
            self.stamp = max(self.stamp, frame.stamp)
        self.changes += 1
        return True

    def estimate(self) -> m.PoseEstimate:
        x, y, th = self.ekf.pose
        return m.PoseEstimate(stamp=self.stamp, x=x, y=y, theta=th,
                              covariance=[float(v) for v in self.ekf.P.ravel()])
