"""The reference path follower: drives the path on ``nav/path`` with pure pursuit, then stops.

    python -m icefloe.services.follower --config deploy/robots/sim.toml
    icefloe pub nav/path '{"points": [{"x": 0, "y": 0}, {"x": 0.5, "y": 0}, {"x": 0.5, "y": 0.5}]}'

It steers with `pursuit.py` (the maths, one small module) from the pose on ``follower.pose``
(``loc/pose`` by default: the world frame the planner plans in), sending numbered commands on
``cmd/twist`` at ``follower.rate_hz`` and a stop at the path's end. It reports on
``nav/status``. A student's own follower replaces it by taking the same key (docs/planning.md).

A stop wins: a stop on ``cmd/stop`` from anyone ends the path at once (and the follower sends a
stop of its own after it, so not even a twist it issued a moment after that stop moves the
wheels); a path issued before a stop that arrives after it, a path older than the deadman, and
an overtaken path are not driven (the rules of hwbridge, `icefloe/ordering.py`). An
empty path ends the one being followed; a pose that stops coming ends it too.
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass

from icefloe.config import RobotConfig
from icefloe.ordering import CommandOrder, Origin
from icefloe.runtime import Node, run
from icefloe.schemas import keys
from icefloe.schemas import messages as m

from .pursuit import Params, Point, step

POSE_TOPICS = {"loc/pose": keys.LOC_POSE, "odom/pose": keys.ODOM_POSE, "sim/truth": keys.TRUTH}
STATUS_PERIOD = 0.25
"""nav/status while following, s (and at every change); 4 times slower when idle."""


@dataclass
class Following:
    path: list[Point]
    sender: str
    seq: int
    params: Params
    since: tuple[int, float] = (0, 0.0)


async def main(config: RobotConfig) -> None:
    f = config.follower
    base = Params(speed=f.speed, lookahead=f.lookahead, max_turn_rate=f.max_turn_rate,
                  turn_in_place=f.turn_in_place, goal_tolerance=f.goal_tolerance)
    order = CommandOrder(deadman_ns=int(config.hwbridge.deadman_s * 1e9))
    stops = 0
    now: Following | None = None
    status = m.FollowStatus(stamp=time.time_ns(), state="idle")
    pose: tuple[float, float, float] | None = None
    pose_at = 0.0

    async with Node("follower", config) as node:
        twist_pub, stop_pub = node.publisher(keys.TWIST), node.publisher(keys.STOP)
        status_pub = node.publisher(keys.NAV_STATUS)
        me = str(node.session.zid())

        def report(new: m.FollowStatus) -> None:
            nonlocal status
            status = new
            status_pub.put(new)

        def end(state: str, reason: str = "", *, stop: bool = True) -> None:
            nonlocal now
            if stop:
                stop_pub.put(node.command(m.Stop))
            if now is not None:
                node.log.info("path from %s #%d: %s%s", now.sender or "?", now.seq, state,
                              f" ({reason})" if reason else "")
                report(m.FollowStatus(stamp=time.time_ns(), state=state, reason=reason, sender=now.sender,
                                      seq=now.seq, points=len(now.path), cross_track=status.cross_track,
                                      remaining=status.remaining))
            now = None

        async def take_stops() -> None:
            nonlocal stops
            async for stop in node.subscribe(keys.STOP):
                if stop.sender == me:
                    continue  # our own, at a path's end
                stops += 1
                order.stop(Origin.of(time.monotonic_ns(), stop.sender, stop.seq, stop.stamp), stops)
                if now is not None:
                    end("stopped", "a stop on cmd/stop")

        async def take_paths() -> None:
            nonlocal now
            async for path in node.subscribe(keys.NAV_PATH):
                _, why = order.motion(Origin.of(time.monotonic_ns(), path.sender, path.seq, path.stamp))
                if why:
                    node.limited.warning("nav/path refused", "nav/path from %s #%d not driven: %s",
                                         path.sender or "?", path.seq, why)
                    report(m.FollowStatus(stamp=time.time_ns(), state=status.state, reason=f"path refused: {why}",
                                          sender=path.sender, seq=path.seq, points=len(path.points)))
                    continue
                if not path.points:
                    end("stopped", "an empty path", stop=now is not None)
                    continue
                speed = min(path.speed or f.speed, f.max_speed)
                if now is not None:
                    end("stopped", "a new path", stop=False)
                now = Following([(float(p.x), float(p.y)) for p in path.points], path.sender, path.seq,
                                Params(**{**base.__dict__, "speed": speed}))
                node.log.info("path from %s #%d: %d points, %.2f m/s", path.sender or "?", path.seq,
                              len(path.points), speed)
                report(m.FollowStatus(stamp=time.time_ns(), state="following", sender=path.sender, seq=path.seq,
                                      points=len(path.points)))

        async def take_poses() -> None:
            nonlocal pose, pose_at
            async for p in node.subscribe(POSE_TOPICS[f.pose]):
                pose, pose_at = (p.x, p.y, p.theta), time.monotonic()

        async def drive() -> None:
            period = 1.0 / f.rate_hz
            deadline = last_status = time.monotonic()
            while True:
                deadline = max(deadline + period, time.monotonic())
                await asyncio.sleep(deadline - time.monotonic())
                t = time.monotonic()
                if now is not None:
                    if pose is None or t - pose_at > f.pose_timeout_s:
                        end("stopped", f"no pose on {f.pose} for {f.pose_timeout_s} s")
                        continue
                    s = step(now.path, pose, now.since, now.params)
                    now.since = s.progress
                    if s.arrived:
                        status_now = m.FollowStatus(stamp=time.time_ns(), state="following", sender=now.sender,
                                                    seq=now.seq, points=len(now.path), cross_track=s.cross_track,
                                                    remaining=0.0)
                        report(status_now)
                        end("arrived")
                        continue
                    twist_pub.put(node.command(m.Twist, v=s.v, w=s.w))
                    if t - last_status >= STATUS_PERIOD:
                        report(m.FollowStatus(stamp=time.time_ns(), state="following", sender=now.sender,
                                              seq=now.seq, points=len(now.path), cross_track=s.cross_track,
                                              remaining=s.remaining))
                        last_status = t
                elif t - last_status >= 4 * STATUS_PERIOD:
                    report(m.FollowStatus(**{**_fields(status), "stamp": time.time_ns()}))
                    last_status = t

        node.log.info("following paths on %s with the pose on %s", node.key(keys.NAV_PATH), f.pose)
        try:
            async with asyncio.TaskGroup() as tasks:
                for job in (take_stops, take_paths, take_poses, drive):
                    tasks.create_task(job())
        finally:
            if now is not None:
                stop_pub.put(node.command(m.Stop))


def _fields(status: m.FollowStatus) -> dict[str, object]:
    return {k: getattr(status, k) for k in status.__struct_fields__}


if __name__ == "__main__":
    run(main)
