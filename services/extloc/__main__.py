"""The lab's external localizer: an overhead camera gives every robot its pose (docs/extloc.md).

    python -m icefloe.services.extloc --config lab.toml     # the lab's config, with [overhead]

One per lab, beside the lab router, not per robot. It reads the overhead camera
(``overhead.source``), finds each robot's top marker (``[extloc]`` of the configs named in
``overhead.robots``) and publishes that robot's pose on the robot's own key
``icefloe/<robot>/extloc/pose``, in the world frame. A robot not seen in a frame gets nothing
for that frame. The camera's pose comes from ``overhead.pose`` (``icefloe extloc calibrate``),
or, without one, from the floor markers in the first frames.

It also serves the old PenguinPi localiser's HTTP API on ``overhead.http_port``, as its clients
read it: ``GET /pose/get?group=N`` in the old square's frame and units, ``GET /camera/get`` its
picture (`oldapi.py`, `oldsquare.py`); and the whole frame, ``GET /camera/frame``.

The work between frames (which robots, the camera's pose, each frame's poses) is `tracker.py`'s;
the capture thread is `icefloe.vision.capture`'s. Here: the wiring.
"""

from __future__ import annotations

import asyncio
import time

import zenoh

from icefloe.config import RobotConfig
from icefloe.errors import BadPayload
from icefloe.runtime import Node, run
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m
from icefloe.vision.capture import Capture

from .oldapi import OldApi, Seen
from .sources import SimOverheadSource, open_overhead
from .tracker import OverheadLocalizer


async def main(config: RobotConfig) -> None:
    ov = config.overhead
    node = Node("extloc", config)
    tracker = OverheadLocalizer(config, node.log)  # ConfigError for a bad lab: run() says so, before the bus
    robots = tracker.robots
    seen = Seen()
    async with node:
        poses = {r.name: node.publisher(keys.EXTLOC_POSE, robot=r.name) for r in robots}
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
        capture = Capture("overhead camera", ov.source, opener, ov.width, ov.height, log=node.log,
                          limited=node.limited, thread_name="extloc-capture")
        capture.start()
        api = OldApi(ov, tracker.group_of, seen, node.log, {top.robot: top.height for top in tracker.tops.values()})
        if ov.http_port:
            await api.start(ov.http_host, ov.http_port)
            node.log.info("old localiser API on http://%s:%d (/pose/get?group=N, /camera/get; /camera/frame), its "
                          "square's corner at (%g, %g) m, its x axis at %g rad", ov.http_host, ov.http_port,
                          ov.old_square_x, ov.old_square_y, ov.old_square_yaw)
        node.log.info("looking for %s", ", ".join(f"{t.robot} (marker {i})" for i, t in sorted(tracker.tops.items())))
        try:
            async for frame in capture.frames("extloc: %d frames captured, %d located, %d dropped (behind the camera)"):
                seen.frame = frame
                located = await asyncio.to_thread(tracker.on_frame, *frame)
                if ov.http_port and seen.camera is None and tracker.locator is not None:  # known from now on
                    api.camera_known(tracker.intrinsics, tracker.locator.pose)
                for robot, pose in located:
                    poses[robot].put(pose)
                    seen.poses[robot] = (time.monotonic(), pose)
        finally:
            await api.stop()
            await capture.close()


if __name__ == "__main__":
    run(main)
