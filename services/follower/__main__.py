"""The reference path follower: drives the path on ``nav/path`` with pure pursuit, then stops.

    python -m icefloe.services.follower --config deploy/robots/sim.toml
    icefloe pub nav/path '{"points": [{"x": 0, "y": 0}, {"x": 0.5, "y": 0}, {"x": 0.5, "y": 0.5}]}'

It steers with `pursuit.py` (the maths, one small module) from the pose on ``follower.pose``
(``loc/pose`` by default: the world frame the planner plans in), sending numbered commands on
``cmd/twist`` at ``follower.rate_hz`` and a stop at the path's end. It reports on
``nav/status``. A student's own follower replaces it by taking the same key (docs/planning.md).

A stop wins, whoever sends it, and a path issued before it is not driven (`tracker.py`, which
holds the follower's state between messages; `__main__` only wires it to the bus).
"""

from __future__ import annotations

import asyncio
import time

from icefloe.config import RobotConfig
from icefloe.runtime import Node, run
from icefloe.schemas import keys
from icefloe.schemas import messages as m

from .tracker import Follower

POSE_TOPICS = {"loc/pose": keys.LOC_POSE, "odom/pose": keys.ODOM_POSE, "sim/truth": keys.TRUTH}


class BusCommands:
    """The follower's output on the bus: numbered commands (`Node.command`) and its status."""

    def __init__(self, node: Node) -> None:
        self._node = node
        self._twist, self._stop = node.publisher(keys.TWIST), node.publisher(keys.STOP)
        self._status = node.publisher(keys.NAV_STATUS)

    def twist(self, v: float, w: float) -> None:
        self._twist.put(self._node.command(m.Twist, v=v, w=w))

    def stop(self) -> None:
        self._stop.put(self._node.command(m.Stop))

    def status(self, status: m.FollowStatus) -> None:
        self._status.put(status)


async def main(config: RobotConfig) -> None:
    f = config.follower
    async with Node("follower", config) as node:
        follower = Follower(config, str(node.session.zid()), BusCommands(node), node.log)

        async def take_stops() -> None:
            async for stop in node.subscribe(keys.STOP):
                follower.on_stop(stop)

        async def take_paths() -> None:
            async for path in node.subscribe(keys.NAV_PATH):
                follower.on_path(path)

        async def take_poses() -> None:
            async for pose in node.subscribe(POSE_TOPICS[f.pose]):
                follower.on_pose(pose)

        async def drive() -> None:
            period = 1.0 / f.rate_hz
            deadline = time.monotonic()
            while True:
                deadline = max(deadline + period, time.monotonic())
                await asyncio.sleep(deadline - time.monotonic())
                follower.tick()

        node.log.info("following paths on %s with the pose on %s", node.key(keys.NAV_PATH), f.pose)
        try:
            async with asyncio.TaskGroup() as tasks:
                for job in (take_stops, take_paths, take_poses, drive):
                    tasks.create_task(job())
        finally:
            follower.close()


if __name__ == "__main__":
    run(main)
