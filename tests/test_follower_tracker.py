"""The follower's state between messages (services/follower/tracker.py), pure logic: paths taken
and refused, stops from others, a pose that stops coming, the status reported. A fake of the bus
output and a clock of the test's own; no processes."""

from __future__ import annotations

import logging

import msgspec

from icefloe.config import RobotConfig
from icefloe.schemas import messages as m
from icefloe.services.follower.tracker import STATUS_PERIOD, Follower

ME = "follower-session"
S = 1_000_000_000  # ns


class FakeCommands:
    """What the follower put on the bus, in order: ("twist", v, w), ("stop",), ("status", FollowStatus)."""

    def __init__(self) -> None:
        self.sent: list[tuple] = []

    def twist(self, v: float, w: float) -> None:
        self.sent.append(("twist", v, w))

    def stop(self) -> None:
        self.sent.append(("stop",))

    def status(self, status: m.FollowStatus) -> None:
        self.sent.append(("status", status))

    def kinds(self) -> list[str]:
        return [item[0] for item in self.sent]

    def statuses(self) -> list[m.FollowStatus]:
        return [item[1] for item in self.sent if item[0] == "status"]


class Clock:
    def __init__(self) -> None:
        self.ns = 1000 * S

    def __call__(self) -> int:
        return self.ns


def follower(**follower_config: object) -> tuple[Follower, FakeCommands, Clock]:
    config = RobotConfig()
    if follower_config:
        config = msgspec.structs.replace(config, follower=msgspec.structs.replace(config.follower,
                                                                                   **follower_config))
    out, clock = FakeCommands(), Clock()
    return Follower(config, ME, out, logging.getLogger("icefloe.follower"), monotonic_ns=clock,
                    wall_ns=lambda: clock.ns + 7), out, clock


def path(*points: tuple[float, float], seq: int = 1, sender: str = "planner", stamp: int = 0) -> m.NavPath:
    return m.NavPath(points=[m.Waypoint(x=x, y=y) for x, y in points], sender=sender, seq=seq, stamp=stamp)


def test_a_path_is_driven_to_its_end_then_a_stop() -> None:
    f, out, clock = follower()
    f.on_path(path((0.0, 0.0), (0.5, 0.0)))
    assert f.now is not None and out.statuses()[-1].state == "following"
    f.on_pose(m.Pose(stamp=1, x=0.0, y=0.0, theta=0.0))
    clock.ns += S // 20
    f.tick()
    kind, v, w = out.sent[-1]
    assert kind == "twist" and v > 0 and abs(w) < 1e-9  # straight ahead along the path
    f.on_pose(m.Pose(stamp=2, x=0.5, y=0.0, theta=0.0))
    clock.ns += S // 20
    f.tick()
    assert out.kinds()[-3:] == ["status", "stop", "status"] and f.now is None
    assert out.statuses()[-1].state == "arrived" and out.statuses()[-1].stamp == clock.ns + 7


def test_a_stop_from_someone_else_ends_the_path_and_an_own_stop_does_not() -> None:
    f, out, _clock = follower()
    f.on_path(path((0.0, 0.0), (1.0, 0.0), seq=5, stamp=100 * S))
    f.on_stop(m.Stop(sender=ME, seq=1))
    assert f.now is not None and f.stops == 0
    f.on_stop(m.Stop(sender="teleop", seq=1, stamp=101 * S))
    assert f.now is None and out.kinds()[-2:] == ["stop", "status"]
    assert (out.statuses()[-1].state, out.statuses()[-1].reason) == ("stopped", "a stop on cmd/stop")


def test_a_path_issued_before_a_stop_is_refused_and_said_so() -> None:
    f, out, _clock = follower()
    f.on_path(path((0.0, 0.0), (1.0, 0.0), seq=7, sender="planner"))
    f.on_stop(m.Stop(sender="planner", seq=9))
    f.on_path(path((0.0, 0.0), (1.0, 0.0), seq=8, sender="planner"))  # issued before that stop
    assert f.now is None
    refused = out.statuses()[-1]
    assert refused.reason.startswith("path refused: ") and refused.seq == 8


def test_a_pose_that_stops_coming_ends_the_path() -> None:
    f, out, clock = follower(pose_timeout_s=0.5)
    f.on_path(path((0.0, 0.0), (1.0, 0.0)))
    f.on_pose(m.PoseEstimate(stamp=1, x=0.0, y=0.0, theta=0.0, covariance=[0.0] * 9))
    clock.ns += int(0.6 * S)
    f.tick()
    assert f.now is None and out.kinds()[-2:] == ["stop", "status"]
    assert out.statuses()[-1].reason == "no pose on loc/pose for 0.5 s"


def test_an_empty_path_ends_the_path_and_costs_nothing_when_idle() -> None:
    f, out, _clock = follower()
    f.on_path(path())
    assert out.sent == []
    f.on_path(path((0.0, 0.0), (1.0, 0.0), seq=2))
    f.on_path(path(seq=3))
    assert f.now is None and out.kinds()[-2:] == ["stop", "status"]
    assert out.statuses()[-1].reason == "an empty path"


def test_idle_status_is_repeated_four_times_slower_and_a_closing_follower_stops_only_if_following() -> None:
    f, out, clock = follower()
    clock.ns += int(3 * STATUS_PERIOD * S)
    f.tick()
    assert out.sent == []
    clock.ns += int(STATUS_PERIOD * S)
    f.tick()
    assert [s.state for s in out.statuses()] == ["idle"]
    f.close()
    assert out.kinds() == ["status"]
    f.on_path(path((0.0, 0.0), (1.0, 0.0)))
    f.close()
    assert out.kinds()[-1] == "stop"
