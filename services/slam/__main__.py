"""slam: EKF-SLAM from ``odom/pose`` and ``camera/landmarks`` to ``slam/pose`` and ``slam/map``.

* The maths is in `ekfslam.py` (one small module: read it first); the bookkeeping
  between messages (odometry increments, late camera frames, bad input) is the
  localizer's (`icefloe/estimation/localizer.py`; `tracker.Slam` puts `EkfSlam` in it).
* Frame: SLAM's own, the robot's pose when the service started (x, y, theta = 0);
  `icefloe score map` aligns its map to the world's.
* Publishes ``slam/pose`` (with the pose's 3 x 3 covariance) after every landmark
  frame and at ``slam.rate_hz``; ``slam/map`` (each landmark with its 2 x 2
  covariance) at ``slam.map_rate_hz``.

Run: ``python -m icefloe.services.slam --config sim``; a robot config runs it under
``icefloe up`` when its ``services`` list names ``slam`` (docs/slam.md).
"""

from __future__ import annotations

import asyncio

from icefloe.config import RobotConfig
from icefloe.runtime import Node, run
from icefloe.schemas import keys

from .tracker import Slam


async def main(config: RobotConfig) -> None:
    async with Node("slam", config) as node:
        slam = Slam(config, node.log)
        pose_pub, map_pub = node.publisher(keys.SLAM_POSE), node.publisher(keys.SLAM_MAP)
        node.log.info("slam: up to %d landmarks, publishing %s and %s", config.slam.max_landmarks,
                      node.key(keys.SLAM_POSE), node.key(keys.SLAM_MAP))

        async def odometry() -> None:
            # Every pose, not only the newest: on a busy robot the loop may fall behind, and a
            # late camera frame is placed on this history (a map error, unlike a pose error, stays).
            async for pose in node.subscribe(keys.ODOM_POSE, latest=False, maxsize=64):
                slam.on_odometry(pose)

        async def landmarks() -> None:
            async for frame in node.subscribe(keys.LANDMARKS, latest=False, maxsize=16):
                if slam.on_landmarks(frame):
                    pose_pub.put(slam.estimate())

        async def steady(period: float, publish) -> None:
            while True:
                await asyncio.sleep(period)
                if slam.stamp:  # nothing to say before the first input
                    publish()

        async with asyncio.TaskGroup() as tasks:
            tasks.create_task(odometry())
            tasks.create_task(landmarks())
            tasks.create_task(steady(1.0 / config.slam.rate_hz, lambda: pose_pub.put(slam.estimate())))
            tasks.create_task(steady(1.0 / config.slam.map_rate_hz, lambda: map_pub.put(slam.landmark_map())))


if __name__ == "__main__":
    run(main)
