"""odometry: dead reckoning from ``hw/wheels`` to ``odom/pose``.

* Once per period (``odometry.rate_hz``, 50 Hz) takes every ``hw/wheels``
  sample that arrived meanwhile, in order, integrates them with the exact arc
  model in `icefloe/estimation/odometry.py` (docs/odometry.md), and publishes ``odom/pose`` (once a
  first sample arrived) if it changed. A sample lost on the way loses no motion: counts are
  cumulative, so the next difference covers it.
* At rest (the pose, v and w as last published) it publishes only a heartbeat, at
  ``odometry.rest_rate_hz`` (`icefloe.heartbeat`), stamped with the latest sample's time: no
  sample rate is assumed (hwbridge may send a still robot's wheels seldom). A period with no
  sample costs a look into Zenoh's queue and nothing else.
* ``odom/reset`` sets the pose (to the `PoseReset` sent, origin if empty) and
  answers with the new `Pose`.
* Glitches (timestamp backwards, count jumps no wheel can make: encoder reset,
  bridge restart) are logged with what was seen, never integrated; the pose
  stays where it was and the next sample is the new reference.

Run: ``python -m icefloe.services.odometry --config sim``.
"""

from __future__ import annotations

import time

from icefloe.config import RobotConfig
from icefloe.estimation.odometry import EventLog, make_odometry, pose_message
from icefloe.heartbeat import Heartbeat
from icefloe.runtime import Node, run
from icefloe.schemas import keys
from icefloe.schemas import messages as m

QUEUE = 4096
"""hw/wheels samples kept between two periods (4 s at 1 kHz). An overflow drops the oldest,
which loses no motion."""


async def main(config: RobotConfig) -> None:
    odo = make_odometry(config)  # the config's values were checked when it was read
    period = 1.0 / config.odometry.rate_hz
    async with Node("odometry", config) as node:
        events = EventLog(node.log)
        pose_pub = node.publisher(keys.ODOM_POSE)
        heartbeat = Heartbeat(1.0 / config.odometry.rest_rate_hz, slack_s=period / 2)
        published: list[tuple[float, ...]] = [()]  # the pose last published, less its stamp

        def publish_if_due(pose: m.Pose, *, changed: bool | None = None) -> None:
            """``pose`` on the bus if it changed (``changed``: whether it did, if known), or the heartbeat is due."""
            motion = (pose.x, pose.y, pose.theta, pose.v, pose.w)
            if heartbeat.due(motion != published[0] if changed is None else changed, time.monotonic()):
                pose_pub.put(pose)
                published[0] = motion

        async def reset(request: m.PoseReset) -> m.Pose:
            odo.reset(request.x, request.y, request.theta)
            node.log.info("pose reset to x=%.3f y=%.3f theta=%.3f", odo.x, odo.y, odo.theta)
            if not odo.stamp:  # no sample yet: nothing on odom/pose, but the answer needs a time
                return m.Pose(stamp=time.time_ns(), x=odo.x, y=odo.y, theta=odo.theta)
            pose = pose_message(odo)
            publish_if_due(pose, changed=True)
            return pose

        node.queryable(keys.ODOM_RESET, reset)

        node.log.info("odometry: k=%.4e m/count, track %.3f m, publishing odom/pose at %.0f Hz while it changes, "
                      "%.0f Hz at rest", odo.geometry.metres_per_tick, odo.geometry.track, config.odometry.rate_hz,
                      config.odometry.rest_rate_hz)
        # One wake-up per period, whatever the wheel rate: at 1 kHz input this costs a third of
        # the CPU a callback per sample does (bench/odometry_localizer.py).
        async for batch in node.batches(keys.WHEELS, period, maxsize=QUEUE):
            for wheels in batch:
                events.note(odo.update(wheels.stamp, wheels.ticks_left, wheels.ticks_right))
            if odo.stamp:  # no sample, no change: only the heartbeat, if it is due
                publish_if_due(pose_message(odo), changed=None if batch else False)


if __name__ == "__main__":
    run(main)
