"""The lab's external localizer: an overhead camera gives every robot its pose (docs/extloc.md).

    python -m icefloe.services.extloc --config lab.toml     # the lab's config, with [overhead]

One per lab, beside the lab router, not per robot. It reads the overhead camera
(``overhead.source``), finds each robot's top marker (``[extloc]`` of the configs named in
``overhead.robots``) and publishes that robot's pose on the robot's own key
``icefloe/<robot>/extloc/pose``, in the world frame. A robot not seen in a frame gets nothing
for that frame. The camera's pose comes from ``overhead.pose`` (``icefloe extloc calibrate``),
or, without one, from the floor markers in the first frames.

It also serves the old PenguinPi localiser's HTTP API on ``overhead.http_port``:
``GET /pose/get?group=N`` and ``GET /camera/get`` (`icefloe.services.extloc.oldapi`).
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections.abc import Callable

import numpy as np
import zenoh

from icefloe import config as config_mod
from icefloe.config import RobotConfig
from icefloe.errors import BadPayload, ConfigError
from icefloe.runtime import Node, run
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m
from icefloe.services.camera.__main__ import LatestFrame
from icefloe.services.camera.detection import BadFrame, check_frame
from icefloe.services.camera.geometry import Intrinsics, load_calibration
from icefloe.services.camera.sources import Source
from icefloe.worldmap import WorldMap, load_world

from . import locate
from .geometry import load_pose
from .oldapi import OldApi, Seen
from .sources import SimOverheadSource, open_overhead

RETRY_S = 2.0
"""A camera that failed is opened again after this long, s."""
REPORT_S = 10.0


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
    ov = config.overhead
    if ov.calibration:
        return load_calibration(ov.calibration, ov.width, ov.height)
    return Intrinsics.nominal(ov.focal_px, ov.width, ov.height)


def capture(config: RobotConfig, node: Node, slot: LatestFrame, stop: threading.Event,
            opener: Callable[[], Source]) -> None:
    """The capture thread: open the source, read frames into ``slot``, reopen after failures."""
    ov = config.overhead
    source: Source | None = None
    while not stop.is_set():
        try:
            if source is None:
                source = opener()
                node.log.info("overhead camera %r open", ov.source)
            stamp, image = source.read()
            slot.put((stamp, check_frame(image, ov.width, ov.height)))
        except BadFrame as exc:
            node.limited.warning("bad frame", "overhead camera %r: bad frame skipped (%s)", ov.source, exc)
        except Exception as exc:  # a camera that fails must not take the service with it
            node.log.warning("overhead camera %r failed: %s; retrying in %.0f s", ov.source, exc, RETRY_S)
            if source is not None:
                with contextlib.suppress(Exception):
                    source.close()
            source = None
            stop.wait(RETRY_S)
    if source is not None:
        source.close()


def external_pose(stamp: int, fix: locate.Fix) -> m.ExternalPose:
    sxy, sth = fix.sigma_xy**2, fix.sigma_theta**2
    return m.ExternalPose(stamp=stamp, x=fix.x, y=fix.y, theta=fix.theta,
                          covariance=[sxy, 0.0, 0.0, 0.0, sxy, 0.0, 0.0, 0.0, sth], side_px=fix.side_px)


async def main(config: RobotConfig) -> None:
    ov = config.overhead
    robots = robot_configs(config)
    world = load_world(ov.world)
    tops = locate.top_markers([locate.TopMarker(r.name, r.extloc.marker_id, r.extloc.marker_size,
                                                r.extloc.marker_height) for r in robots], world, ov.dictionary)
    group_of = groups(robots, config.source)
    intrinsics = overhead_intrinsics(config)
    camera_pose = load_pose(ov.pose, ov.width, ov.height) if ov.pose else None
    seen = Seen()
    async with Node("extloc", config) as node:
        poses = {r.name: node.publisher(keys.EXTLOC_POSE, robot=r.name) for r in robots}
        slot, stop = LatestFrame(), threading.Event()
        sim = SimOverheadSource(ov, robots) if ov.source == "sim" else None
        if sim is not None:
            for robot in robots:
                def on_truth(sample: zenoh.Sample, name: str = robot.name) -> None:  # a Zenoh reader thread
                    if not keys.is_concrete(str(sample.key_expr)):
                        return  # a truth put on a wildcard is nobody's
                    try:
                        sim.set_truth(name, codec.decode(sample.payload.to_bytes(), str(sample.encoding), m.Truth,
                                                         str(sample.key_expr)))
                    except BadPayload as exc:  # the simulated camera keeps the robot's last truth
                        node.limited.warning("truth", "dropped a bad sim/truth: %s", exc)
                node.on_samples(keys.key(robot.name, keys.TRUTH), on_truth)
        opener = (lambda: sim) if sim is not None else (lambda: open_overhead(ov, robots))
        thread = threading.Thread(target=capture, args=(config, node, slot, stop, opener),
                                  name="extloc-capture", daemon=True)
        thread.start()
        api = OldApi(ov, group_of, seen)
        if ov.http_port:
            await api.start(ov.http_host, ov.http_port)
            node.log.info("old localiser API on http://%s:%d (/pose/get?group=N, /camera/get)",
                          ov.http_host, ov.http_port)
        locator: locate.Locator | None = None
        if camera_pose is not None:
            locator = locate.Locator(ov.dictionary, intrinsics, camera_pose, tops)
        node.log.info("looking for %s", ", ".join(f"{t.robot} (marker {i})" for i, t in sorted(tops.items())))
        next_report, located = time.monotonic() + REPORT_S, 0
        try:
            while True:
                frame = await asyncio.to_thread(slot.take, 0.5)
                if time.monotonic() >= next_report:
                    next_report = time.monotonic() + REPORT_S
                    if slot.dropped:
                        node.log.info("extloc: %d frames captured, %d located, %d dropped (behind the camera)",
                                      slot.captured, located, slot.dropped)
                if frame is None:
                    continue
                stamp, image = frame
                seen.frame = frame
                if locator is None:
                    locator = await asyncio.to_thread(calibrate_from, node, intrinsics, world, image, ov.dictionary,
                                                      tops)
                    if locator is None:
                        continue
                fixes = await asyncio.to_thread(locator.locate, image)
                located += 1
                for fix in fixes:
                    message = external_pose(stamp, fix)
                    poses[fix.robot].put(message)
                    seen.poses[fix.robot] = (time.monotonic(), message)
        finally:
            stop.set()
            await api.stop()
            await asyncio.to_thread(thread.join, RETRY_S + 1.0)


def calibrate_from(node: Node, intrinsics: Intrinsics, world: WorldMap, image: np.ndarray, dictionary: str,
                   tops: dict[int, locate.TopMarker]) -> locate.Locator | None:
    """The camera's pose from the floor markers in ``image`` (no ``overhead.pose``): a `Locator`,
    or None (and a rate-limited line saying why) if too few are in view."""
    try:
        found = locate.calibrate(intrinsics, world, locate.find_markers(locate.make_detector(dictionary), image))
    except locate.CalibrationFailed as exc:
        node.limited.warning("calibration", "cannot find the overhead camera's pose yet: %s", exc)
        return None
    lens = found.pose.lens
    node.log.info("overhead camera found from floor markers %s: lens at (%.3f, %.3f, %.3f) m, reprojection "
                  "error %.2f px RMS, %.1f mm RMS on the floor", found.markers, *lens, found.rms_px,
                  found.rms_floor_m * 1000)
    return locate.Locator(dictionary, intrinsics, found.pose, tops)


if __name__ == "__main__":
    run(main)
