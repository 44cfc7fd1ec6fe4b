"""odometry: dead reckoning from ``hw/wheels`` to ``odom/pose``.

* Once per period (``odometry.rate_hz``, 50 Hz) takes every ``hw/wheels``
  sample that arrived meanwhile, in order, integrates them with the exact arc
  model in `model.py` (docs/odometry.md), and publishes ``odom/pose`` (once a
  first sample arrived). A sample lost on the way loses no motion: counts are
  cumulative, so the next difference covers it.
* ``odom/reset`` sets the pose (to the `PoseReset` sent, origin if empty) and
  answers with the new `Pose`.
* Glitches (timestamp backwards, count jumps no wheel can make: encoder reset,
  bridge restart) are logged with what was seen, never integrated; the pose
  stays where it was and the next sample is the new reference.

Run: ``python -m icefloe.services.odometry --config sim``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import ClassVar

from icefloe.config import RobotConfig
from icefloe.logs import LimitedLog
from icefloe.runtime import Node, run
from icefloe.schemas import keys
from icefloe.schemas import messages as m

from .model import Event, Geometry, Limits, Odometry, Step

QUEUE = 4096
"""hw/wheels samples kept between two periods (4 s at 1 kHz). An overflow drops the oldest,
which loses no motion."""


def make_odometry(config: RobotConfig) -> Odometry:
    """The pure integrator configured from the robot config."""
    g, o = config.geometry, config.odometry
    return Odometry(
        Geometry(g.wheel_diameter, g.track, g.ticks_per_rev),
        Limits(o.max_wheel_speed, o.jump_margin, o.gap_s, o.speed_window_s),
    )


def pose_message(odo: Odometry) -> m.Pose:
    v, w = odo.speeds()
    return m.Pose(stamp=odo.stamp, x=odo.x, y=odo.y, theta=odo.theta, v=v, w=w)


class EventLog:
    """Logs each unusual sample with what was seen: up to `burst` lines per kind per second.

    A storm (say, a board that keeps resetting) becomes a few lines plus a
    count instead of a thousand lines a second (`LimitedLog`).
    """

    INTERESTING: ClassVar[dict[Event, int]] = {Event.GAP: logging.INFO, Event.BACKWARDS: logging.WARNING,
                                               Event.JUMP: logging.WARNING, Event.BAD: logging.WARNING}

    def __init__(self, log: logging.Logger, clock: Callable[[], float] = time.monotonic, burst: int = 5) -> None:
        self._limited = LimitedLog(log, burst=burst, limit=2 * burst, clock=clock)
        self.counts: dict[Event, int] = {e: 0 for e in Event}
        """Samples seen per kind, since start."""

    def note(self, step: Step) -> None:
        self.counts[step.event] += 1
        level = self.INTERESTING.get(step.event)
        if level is not None:
            self._limited.write(level, f"hw/wheels {step.event.name.lower()}", "hw/wheels: %s", step.describe())


async def main(config: RobotConfig) -> None:
    odo = make_odometry(config)  # the config's values were checked when it was read
    period = 1.0 / config.odometry.rate_hz
    async with Node("odometry", config) as node:
        events = EventLog(node.log)
        pose_pub = node.publisher(keys.ODOM_POSE)

        async def reset(request: m.PoseReset) -> m.Pose:
            odo.reset(request.x, request.y, request.theta)
            node.log.info("pose reset to x=%.3f y=%.3f theta=%.3f", odo.x, odo.y, odo.theta)
            if not odo.stamp:  # no sample yet: nothing on odom/pose, but the answer needs a time
                return m.Pose(stamp=time.time_ns(), x=odo.x, y=odo.y, theta=odo.theta)
            pose = pose_message(odo)
            pose_pub.put(pose)
            return pose

        node.queryable(keys.ODOM_RESET, reset)

        node.log.info("odometry: k=%.4e m/count, track %.3f m, publishing odom/pose at %.0f Hz",
                      odo.geometry.metres_per_tick, odo.geometry.track, config.odometry.rate_hz)
        # One wake-up per period, whatever the wheel rate: at 1 kHz input this costs a third of
        # the CPU a callback per sample does (bench/odometry_localizer.py).
        async for batch in node.batches(keys.WHEELS, period, maxsize=QUEUE):
            for wheels in batch:
                events.note(odo.update(wheels.stamp, wheels.ticks_left, wheels.ticks_right))
            if odo.stamp:
                pose_pub.put(pose_message(odo))


if __name__ == "__main__":
    run(main)
