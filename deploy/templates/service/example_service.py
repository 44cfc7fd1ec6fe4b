"""example_service: publishes how far the robot has driven (your own icefloe service).

Made by ``icefloe new-service example_service``: a service in the shape of every
icefloe service (icefloe's own ``services/info`` is the smallest). Make it yours:

    icefloe up robot.toml                  # the simulated robot, with this service
    icefloe echo example_service/distance  # in another terminal: what it publishes
    icefloe teleop                         # drive, and watch the distance grow
    python -m pytest test_example_service.py   # its tests, no robot needed

What it uses from the robot: ``odom/pose`` (`Pose`, x and y in m). What it adds:
``example_service/distance`` (`Distance`, below), and its liveliness token
``icefloe/<robot>/alive/example_service``, which `icefloe status` lists.
"""

from __future__ import annotations

import math

from icefloe.config import RobotConfig
from icefloe.runtime import Node, run
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.schemas.keys import Topic

NAME = "example_service"


class Distance(m.Message):
    """``example_service/distance``: the path driven since this service started."""

    stamp: int
    """When, ns since the epoch (the stamp of the pose it was computed from)."""
    metres: float
    """Path length, m."""


DISTANCE = Topic(f"{NAME}/distance", Distance, "out")
"""Our own key, ``icefloe/<robot>/example_service/distance``, and its message."""


def step(before: m.Pose, after: m.Pose) -> float:
    """The straight-line distance between two poses, m (they come at 50 Hz)."""
    return math.hypot(after.x - before.x, after.y - before.y)


async def main(config: RobotConfig) -> None:
    # A Zenoh session, a logger (also on the bus key `log`), the liveliness token:
    async with Node(NAME, config) as node:
        distance = node.publisher(DISTANCE)
        node.log.info("publishing %s", node.key(DISTANCE))
        total, last = 0.0, None
        # Typed messages, an async iterator; every one, in order (latest=False):
        # a path needs each step.
        async for pose in node.subscribe(keys.ODOM_POSE, latest=False):
            if last is not None:
                total += step(last, pose)
            last = pose
            distance.put(Distance(stamp=pose.stamp, metres=total))


if __name__ == "__main__":
    # --config (default: $ICEFLOE_CONFIG, which `icefloe up` sets); exits on Ctrl-C.
    run(main)
