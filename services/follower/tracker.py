"""The follower's state between bus messages: the path being followed, the latest pose, the
stops, and what to send. No bus here: `__main__.py` feeds it ``cmd/stop``, ``nav/path`` and the
pose, calls `Follower.tick` at ``follower.rate_hz``, and puts what it says on the bus through
`Commands`; the tests feed it the same messages and a clock of their own.

A stop wins: a stop on ``cmd/stop`` from anyone ends the path at once (and the follower sends a
stop of its own after it, so not even a twist it issued a moment after that stop moves the
wheels); a path issued before a stop that arrives after it, a path older than the deadman, and
an overtaken path are not driven (the rules of hwbridge, `icefloe/ordering.py`). An empty path
ends the one being followed; a pose that stops coming ends it too.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from icefloe.config import RobotConfig
from icefloe.logs import LimitedLog
from icefloe.ordering import CommandOrder, Origin
from icefloe.schemas import messages as m

from .pursuit import Params, Point, step

STATUS_PERIOD = 0.25
"""nav/status while following, s (and at every change); 4 times slower when idle."""


class Commands(Protocol):
    """Where the follower's output goes: numbered ``cmd/twist`` and ``cmd/stop``, and ``nav/status``."""

    def twist(self, v: float, w: float) -> None: ...

    def stop(self) -> None: ...

    def status(self, status: m.FollowStatus) -> None: ...


@dataclass
class Following:
    path: list[Point]
    sender: str
    seq: int
    params: Params
    since: tuple[int, float] = (0, 0.0)


class Follower:
    """``config``: the robot's (``[follower]``, and hwbridge's deadman); ``me``: the sender id of this
    follower's own commands (its stops are not stops from someone else). Clocks: ``monotonic_ns``
    for the ages of paths and poses, ``wall_ns`` for the stamps of ``nav/status``."""

    def __init__(self, config: RobotConfig, me: str, out: Commands, log: logging.Logger, *,
                 monotonic_ns: Callable[[], int] = time.monotonic_ns,
                 wall_ns: Callable[[], int] = time.time_ns) -> None:
        f = self.config = config.follower
        self.base = Params(speed=f.speed, lookahead=f.lookahead, max_turn_rate=f.max_turn_rate,
                           turn_in_place=f.turn_in_place, goal_tolerance=f.goal_tolerance)
        self.order = CommandOrder(deadman_ns=int(config.hwbridge.deadman_s * 1e9))
        self.me, self.out, self.log = me, out, log
        self._limited = LimitedLog(log)
        self._monotonic_ns, self._wall_ns = monotonic_ns, wall_ns
        self.stops = 0
        """Stops from others seen so far."""
        self.now: Following | None = None
        """The path being followed."""
        self.status = m.FollowStatus(stamp=wall_ns(), state="idle")
        """The latest ``nav/status`` sent."""
        self.pose: tuple[float, float, float] | None = None
        self._pose_at = 0.0
        self._last_status = self._seconds()

    def _seconds(self) -> float:
        return self._monotonic_ns() / 1e9

    def _report(self, status: m.FollowStatus) -> None:
        self.status = status
        self.out.status(status)

    def _end(self, state: str, reason: str = "", *, stop: bool = True) -> None:
        if stop:
            self.out.stop()
        now = self.now
        if now is not None:
            self.log.info("path from %s #%d: %s%s", now.sender or "?", now.seq, state, f" ({reason})" if reason else "")
            self._report(m.FollowStatus(stamp=self._wall_ns(), state=state, reason=reason, sender=now.sender,
                                        seq=now.seq, points=len(now.path), cross_track=self.status.cross_track,
                                        remaining=self.status.remaining))
        self.now = None

    def on_stop(self, stop: m.Stop) -> None:
        if stop.sender == self.me:
            return  # our own, at a path's end
        self.stops += 1
        self.order.stop(Origin.of(self._monotonic_ns(), stop.sender, stop.seq, stop.stamp), self.stops)
        if self.now is not None:
            self._end("stopped", "a stop on cmd/stop")

    def on_path(self, path: m.NavPath) -> None:
        _, why = self.order.motion(Origin.of(self._monotonic_ns(), path.sender, path.seq, path.stamp))
        if why:
            self._limited.warning("nav/path refused", "nav/path from %s #%d not driven: %s",
                                  path.sender or "?", path.seq, why)
            self._report(m.FollowStatus(stamp=self._wall_ns(), state=self.status.state, reason=f"path refused: {why}",
                                        sender=path.sender, seq=path.seq, points=len(path.points)))
            return
        if not path.points:
            self._end("stopped", "an empty path", stop=self.now is not None)
            return
        speed = min(path.speed or self.config.speed, self.config.max_speed)
        if self.now is not None:
            self._end("stopped", "a new path", stop=False)
        self.now = Following([(float(p.x), float(p.y)) for p in path.points], path.sender, path.seq,
                             Params(**{**self.base.__dict__, "speed": speed}))
        self.log.info("path from %s #%d: %d points, %.2f m/s", path.sender or "?", path.seq, len(path.points), speed)
        self._report(m.FollowStatus(stamp=self._wall_ns(), state="following", sender=path.sender, seq=path.seq,
                                    points=len(path.points)))

    def on_pose(self, pose: m.PoseEstimate | m.Pose | m.Truth) -> None:
        self.pose, self._pose_at = (pose.x, pose.y, pose.theta), self._seconds()

    def tick(self) -> None:
        """One control period: steer along the path (or end it), and report when it is time."""
        t = self._seconds()
        now = self.now
        if now is not None:
            f = self.config
            if self.pose is None or t - self._pose_at > f.pose_timeout_s:
                self._end("stopped", f"no pose on {f.pose} for {f.pose_timeout_s} s")
                return
            s = step(now.path, self.pose, now.since, now.params)
            now.since = s.progress
            if s.arrived:
                self._report(m.FollowStatus(stamp=self._wall_ns(), state="following", sender=now.sender, seq=now.seq,
                                            points=len(now.path), cross_track=s.cross_track, remaining=0.0))
                self._end("arrived")
                return
            self.out.twist(s.v, s.w)
            if t - self._last_status >= STATUS_PERIOD:
                self._report(m.FollowStatus(stamp=self._wall_ns(), state="following", sender=now.sender, seq=now.seq,
                                            points=len(now.path), cross_track=s.cross_track, remaining=s.remaining))
                self._last_status = t
        elif t - self._last_status >= 4 * STATUS_PERIOD:
            self._report(m.FollowStatus(**{**_fields(self.status), "stamp": self._wall_ns()}))
            self._last_status = t

    def close(self) -> None:
        """The service is stopping: a stop if a path was being followed."""
        if self.now is not None:
            self.out.stop()


def _fields(status: m.FollowStatus) -> dict[str, object]:
    return {k: getattr(status, k) for k in status.__struct_fields__}
