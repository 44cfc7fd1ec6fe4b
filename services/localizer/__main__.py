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
* Odometry is read, not followed: the newest ``odom/pose`` is taken at each tick and before each
  landmark frame (`Node.latest`: no Python runs for the 50 poses a second between; the increment
  between two poses read is one motion, and the EKF's noise grows with distance, not steps).
* Publishes ``loc/pose`` after every landmark frame, and at each tick of ``localizer.rate_hz``
  that no frame's pose went out before, while the estimate changes (odometry moves it): the
  faster of the two rates (about 20 a second with frames at 15, not 35), never two periods
  without a pose. While nothing changes it (the robot stands, the camera rests), only a
  heartbeat at ``localizer.rest_rate_hz`` (`icefloe.heartbeat`).

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
        odometry = node.latest(keys.ODOM_POSE)
        published = [-1]  # loc.changes when loc/pose was last published
        framed = [False]  # a frame's pose went out since the last tick
        node.log.info("localizer: %d landmarks from %s, init %s", len(loc.ekf.landmarks),
                      config.localizer.world, config.localizer.init)

        def follow_odometry() -> None:
            """Fold in the motion up to the newest pose (one already seen is no motion: `on_odometry`)."""
            pose = odometry.get()
            if pose is not None:
                loc.on_odometry(pose)

        def publish_if_due(*, frame: bool = False) -> None:
            """``loc/pose`` after a landmark frame, or when the estimate changed or the heartbeat is due."""
            if heartbeat.due(frame or loc.changes != published[0], time.monotonic()):
                pub.put(loc.estimate())
                published[0] = loc.changes

        async def landmarks() -> None:
            async for frame in node.subscribe(keys.LANDMARKS, latest=False, maxsize=16):
                follow_odometry()  # the motion up to now: the frame is placed at its own time
                if loc.on_landmarks(frame):
                    publish_if_due(frame=True)
                    framed[0] = True

        async def steady() -> None:
            while True:
                await asyncio.sleep(period)
                if framed[0]:  # this tick's pose went out with a frame: nothing to add
                    framed[0] = False
                    continue
                follow_odometry()
                if loc.initialised and loc.stamp:  # nothing to say before the first input
                    publish_if_due()

        async with asyncio.TaskGroup() as tasks:
            for job in (landmarks, steady):
                tasks.create_task(job())


if __name__ == "__main__":
    run(main)
