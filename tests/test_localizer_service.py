"""The localizer service as a real process: odom/pose and camera/landmarks in (from this test), loc/pose out."""

from __future__ import annotations

import asyncio
import math
import signal
import time

from conftest import wait_for

from icefloe.angles import wrap_angle
from icefloe.errors import EXIT_CONFIG
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.worldmap import load_world

LAB = {mk.id: (mk.x, mk.y) for mk in load_world("lab").markers}


def sight(pose: tuple[float, float, float], lid: int) -> m.Landmark:
    mx, my = LAB[lid]
    x, y, th = pose
    return m.Landmark(id=lid, range=math.hypot(mx - x, my - y),
                      bearing=wrap_angle(math.atan2(my - y, mx - x) - th))


async def collect(sub, into: list) -> None:
    async for msg in sub:
        into.append(msg)


async def test_localizer_process_tracks_gates_and_survives(robot) -> None:
    proc = robot.start("localizer")
    async with robot.node("tester") as node:
        estimates: list[m.PoseEstimate] = []
        logs: list[m.Log] = []
        tasks = [asyncio.create_task(collect(node.subscribe(keys.LOC_POSE, latest=False), estimates)),
                 asyncio.create_task(collect(node.subscribe(keys.LOG, latest=False), logs))]
        odom = node.publisher(keys.ODOM_POSE)
        cam = node.publisher(keys.LANDMARKS)
        stamp = time.time_ns()
        truth = (0.06, -0.04, 0.03)  # config start is (0, 0, 0) with 0.1 m / 0.1 rad std dev

        # Frames of the east wall's markers until the localizer answers (it is up) and has converged.
        deadline = time.monotonic() + 30
        while not estimates or math.hypot(estimates[-1].x - truth[0], estimates[-1].y - truth[1]) > 0.005:
            assert proc.alive(), proc.output
            assert time.monotonic() < deadline, f"no convergence: {estimates[-1:]}\n{proc.output}"
            stamp += 66_000_000
            cam.put(m.Landmarks(stamp=stamp, landmarks=[sight(truth, i) for i in (0, 1, 2)]))
            await asyncio.sleep(0.05)
        est = estimates[-1]
        assert abs(wrap_angle(est.theta - truth[2])) < 0.005
        assert len(est.covariance) == 9
        initial_trace = 2 * 0.1**2 + 0.1**2
        assert est.covariance[0] + est.covariance[4] + est.covariance[8] < 0.2 * initial_trace

        # Odometry: 0.1 m straight ahead in 10 steps of 20 ms, from an odometry frame elsewhere.
        o = (5.0, 5.0, math.pi / 2)
        for i in range(11):
            stamp += 20_000_000
            odom.put(m.Pose(stamp=stamp, x=o[0], y=o[1] + 0.01 * i, theta=o[2]))
            # The first pose is only the reference: let it arrive before the motion starts.
            await asyncio.sleep(0.3 if i == 0 else 0.005)
        moved = (est.x + 0.1 * math.cos(est.theta), est.y + 0.1 * math.sin(est.theta))
        await wait_for(lambda: estimates[-1].stamp == stamp)
        await wait_for(lambda: math.hypot(estimates[-1].x - moved[0], estimates[-1].y - moved[1]) < 1e-6)

        # The odometry is reset (its pose jumps to the origin): not motion, the estimate stays.
        before = estimates[-1]
        stamp += 20_000_000
        odom.put(m.Pose(stamp=stamp, x=0.0, y=0.0, theta=0.0))
        await wait_for(lambda: any("odom/pose jumped" in log.text for log in logs))

        # An outlier (a marker 1 m from where it should be) and an unknown id: rejected, counted, logged.
        stamp += 66_000_000
        bad = sight((moved[0], moved[1], truth[2]), 1)
        cam.put(m.Landmarks(stamp=stamp, landmarks=[
            m.Landmark(id=1, range=bad.range + 1.0, bearing=bad.bearing), m.Landmark(id=77, range=1.0, bearing=0.0)]))
        await wait_for(lambda: any("Mahalanobis" in log.text for log in logs))
        await wait_for(lambda: any("landmark 77: unknown" in log.text for log in logs))
        seen = len(estimates)
        await wait_for(lambda: len(estimates) > seen + 2)
        after = estimates[-1]
        assert math.hypot(after.x - before.x, after.y - before.y) < 1e-9
        assert after.theta == before.theta

        # A payload that does not decode: dropped with a message naming the field, service alive.
        node.session.put(node.key(keys.LANDMARKS), b'{"stamp": 1, "landmarks": [{"id": 1, "range": "far"}]}',
                         encoding="application/json")
        await wait_for(lambda: any("dropped" in log.text and "range" in log.text for log in logs))
        assert proc.alive()
        for task in tasks:
            task.cancel()
    assert proc.stop(signal.SIGINT) == 0, proc.output


async def test_localizer_with_a_bad_world_says_so_and_exits(make_robot) -> None:
    # (Bad values, such as sigma_bearing = 0, are refused when the config is read: tests/test_config.py.)
    robot = make_robot('[localizer]\nworld = "no-such-world.toml"\n')
    proc = robot.start("localizer")
    deadline = time.monotonic() + 30
    while proc.alive():
        assert time.monotonic() < deadline, proc.output
        await asyncio.sleep(0.1)
    assert proc.popen.returncode == EXIT_CONFIG
    assert "no-such-world: no world file of that name (known: " in proc.output and "lab" in proc.output
