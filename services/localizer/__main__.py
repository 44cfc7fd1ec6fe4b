"""localizer: an EKF over (x, y, theta) from ``odom/pose`` and ``camera/landmarks`` to ``loc/pose``.

* Motion: the increment between consecutive ``odom/pose`` messages (in the
  robot's frame, so the odometry frame's origin does not matter). An
  increment no robot can make (odometry reset or restarted, timestamp going
  backwards) is skipped with one log line.
* Measurements: each landmark's range and bearing against the map
  ``localizer.world``; outliers fail a Mahalanobis gate, unknown ids are
  ignored; both are counted and logged (at most one line a second).
* Initial pose: ``localizer.init = "config"`` starts at ``initial_x/y/theta``
  with ``initial_sigma_*``; ``"landmarks"`` waits for the first frame with two
  or more known markers and solves the pose from it (`pose_from_landmarks`).
* Publishes ``loc/pose`` after every landmark frame and at ``localizer.rate_hz`` while the
  estimate changes (odometry moves it); while nothing changes it (the robot stands, the camera
  rests), only a heartbeat at ``localizer.rest_rate_hz`` (`icefloe.heartbeat`).

Run: ``python -m icefloe.services.localizer --config sim``.
"""

from __future__ import annotations

import asyncio
import time

from icefloe.config import RobotConfig
from icefloe.estimation.localizer import Localizer
from icefloe.heartbeat import Heartbeat
from icefloe.runtime import Node, run
from icefloe.schemas import keys


async def main(config: RobotConfig) -> None:
    async with Node("localizer", config) as node:
        loc = Localizer(config, node.log)  # ConfigError for a bad world file: run() says so, exits
        period = 1.0 / config.localizer.rate_hz
        pub = node.publisher(keys.LOC_POSE)
        heartbeat = Heartbeat(1.0 / config.localizer.rest_rate_hz, slack_s=period / 2)
        published = [-1]  # loc.changes when loc/pose was last published
        node.log.info("localizer: %d landmarks from %s, init %s", len(loc.ekf.landmarks),
                      config.localizer.world, config.localizer.init)

        def publish_if_due(*, frame: bool = False) -> None:
            """``loc/pose`` after a landmark frame, or when the estimate changed or the heartbeat is due."""
            if heartbeat.due(frame or loc.changes != published[0], time.monotonic()):
                pub.put(loc.estimate())
                published[0] = loc.changes

        async def odometry() -> None:
            async for pose in node.subscribe(keys.ODOM_POSE):
                loc.on_odometry(pose)

        async def landmarks() -> None:
            async for frame in node.subscribe(keys.LANDMARKS, latest=False, maxsize=16):
                if loc.on_landmarks(frame):
                    publish_if_due(frame=True)

        async def steady() -> None:
            while True:
                await asyncio.sleep(period)
                if loc.initialised and loc.stamp:  # nothing to say before the first input
                    publish_if_due()

        async with asyncio.TaskGroup() as tasks:
            for job in (odometry, landmarks, steady):
                tasks.create_task(job())


if __name__ == "__main__":
    run(main)
