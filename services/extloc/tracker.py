"""The lab's localizer between frames: which robots to look for, where the camera hangs, and each
frame's robots as ``ExternalPose`` messages. No bus here: `__main__.py` feeds it the overhead
camera's frames; the tests feed it the simulator's.

The camera's pose comes from ``overhead.pose`` (``icefloe extloc calibrate``), or, without one,
from the floor markers of the first frame that shows enough of them (`OverheadLocalizer.on_frame`).
"""

from __future__ import annotations

import logging

import numpy as np

from icefloe import config as config_mod
from icefloe.config import RobotConfig
from icefloe.errors import ConfigError
from icefloe.logs import LimitedLog
from icefloe.schemas import messages as m
from icefloe.vision.geometry import Intrinsics, load_calibration
from icefloe.vision.overhead import load_pose
from icefloe.worldmap import load_world

from . import locate


def robot_configs(config: RobotConfig) -> list[RobotConfig]:
    """The configs of ``overhead.robots``; `ConfigError` naming the lab's file for none."""
    if not config.overhead.robots:
        raise ConfigError(f"{config.source}: overhead.robots: no robots to look for")
    return [config_mod.load(name) for name in config.overhead.robots]


def groups(robots: list[RobotConfig], source: str) -> dict[int, str]:
    """The old localiser's group number → robot: ``extloc.group`` where set, else the robot's
    place in ``overhead.robots`` (1, 2, ...); `ConfigError` for a number two robots have."""
    out: dict[int, str] = {}
    for place, robot in enumerate(robots, start=1):
        group = robot.extloc.group or place
        if group in out:
            raise ConfigError(f"{source}: overhead.robots: group {group} is both {out[group]}'s and "
                              f"{robot.name}'s (set extloc.group in their configs)")
        out[group] = robot.name
    return out


def overhead_intrinsics(config: RobotConfig) -> Intrinsics:
    """The overhead camera's lens: its calibration file (``overhead.calibration``), else nominal."""
    ov = config.overhead
    if ov.calibration:
        return load_calibration(ov.calibration, ov.width, ov.height)
    return Intrinsics.nominal(ov.focal_px, ov.width, ov.height)


def external_pose(stamp: int, fix: locate.Fix) -> m.ExternalPose:
    """One robot seen in a frame stamped ``stamp`` ns, as the message its ``extloc/pose`` carries."""
    sxy, sth = fix.sigma_xy**2, fix.sigma_theta**2
    return m.ExternalPose(stamp=stamp, x=fix.x, y=fix.y, theta=fix.theta,
                          covariance=[sxy, 0.0, 0.0, 0.0, sxy, 0.0, 0.0, 0.0, sth], side_px=fix.side_px)


class OverheadLocalizer:
    """The lab's robots and the overhead camera, from the lab's config (`ConfigError` for a bad one,
    before anything starts); `on_frame` turns a frame into each seen robot's pose."""

    def __init__(self, config: RobotConfig, log: logging.Logger) -> None:
        ov = config.overhead
        self.robots = robot_configs(config)
        self.world = load_world(ov.world)
        self.tops = locate.top_markers([locate.TopMarker(r.name, r.extloc.marker_id, r.extloc.marker_size,
                                                         r.extloc.marker_height) for r in self.robots],
                                       self.world, ov.dictionary)
        self.group_of = groups(self.robots, config.source)
        """The old localiser's group numbers (`groups`)."""
        self.intrinsics = overhead_intrinsics(config)
        self.dictionary = ov.dictionary
        camera_pose = load_pose(ov.pose, ov.width, ov.height) if ov.pose else None
        self.locator: locate.Locator | None = None
        """None until the camera's pose is known."""
        if camera_pose is not None:
            self.locator = locate.Locator(ov.dictionary, self.intrinsics, camera_pose, self.tops)
        self.log = log
        self._limited = LimitedLog(log)

    def on_frame(self, stamp: int, image: np.ndarray) -> list[tuple[str, m.ExternalPose]]:
        """(robot, its pose) for each robot seen in ``image``, taken at ``stamp`` ns; none while the
        camera's pose is not known yet (this frame's floor markers are tried first). Blocking
        (OpenCV, some ms): call it on a worker thread."""
        if self.locator is None:
            self.locator = self._calibrate_from(image)
            if self.locator is None:
                return []
        return [(fix.robot, external_pose(stamp, fix)) for fix in self.locator.locate(image)]

    def _calibrate_from(self, image: np.ndarray) -> locate.Locator | None:
        """The camera's pose from the floor markers in ``image`` (no ``overhead.pose``): a `Locator`,
        or None (and a rate-limited line saying why) if too few are in view."""
        try:
            found = locate.calibrate(self.intrinsics, self.world,
                                     locate.find_markers(locate.make_detector(self.dictionary), image))
        except locate.CalibrationFailed as exc:
            self._limited.warning("calibration", "cannot find the overhead camera's pose yet: %s", exc)
            return None
        lens = found.pose.lens
        self.log.info("overhead camera found from floor markers %s: lens at (%.3f, %.3f, %.3f) m, reprojection "
                      "error %.2f px RMS, %.1f mm RMS on the floor", found.markers, *lens, found.rms_px,
                      found.rms_floor_m * 1000)
        return locate.Locator(self.dictionary, self.intrinsics, found.pose, self.tops)
