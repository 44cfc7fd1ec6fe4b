"""End to end with real processes: sim + hwbridge + odometry + localizer, against the simulator's truth.

The test drives the robot with ``cmd/twist`` and plays the camera: it turns
each ``sim/truth`` sample into the landmark sightings the camera would make
(`icefloe.testing.TruthCamera`: field of view, range, noise, seeded) and publishes them on
``camera/landmarks``. Everything else is the real stack over a real router.
"""

from __future__ import annotations

import asyncio
import bisect
import itertools
import math
import random

from conftest import wait_for

from icefloe.angles import wrap_angle
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.testing import TruthCamera, play_camera

LEGS = [(0.2, 0.0, 2.5), (0.0, 1.5, math.pi / 3)] * 4  # (v m/s, w rad/s, s): a rough 0.5 m square


async def collect(sub, into: list) -> None:
    async for msg in sub:
        into.append(msg)


async def drive_square(robot, *, with_camera: bool) -> tuple[list, list, list, TruthCamera]:
    """Start the stack, drive LEGS, stop; return truth, odom/pose, loc/pose messages and the camera played."""
    procs = [robot.start(s) for s in ("sim", "hwbridge", "odometry", *(("localizer",) if with_camera else ()))]
    truth: list[m.Truth] = []
    odom: list[m.Pose] = []
    loc: list[m.PoseEstimate] = []
    camera = TruthCamera(robot.config, random.Random(7))
    async with robot.node("tester") as node:
        truths = (play_camera(node, camera, on_truth=lambda t, _frame: truth.append(t)) if with_camera else
                  collect(node.subscribe(keys.TRUTH, latest=False), truth))
        tasks = [asyncio.create_task(truths),
                 asyncio.create_task(collect(node.subscribe(keys.ODOM_POSE, latest=False), odom)),
                 asyncio.create_task(collect(node.subscribe(keys.LOC_POSE, latest=False), loc))]
        await wait_for(lambda: truth and odom and (loc or not with_camera), timeout=40)
        await drive_legs(node)
        for task in tasks:
            task.cancel()
    check_exits(procs)
    return truth, odom, loc, camera


async def drive_legs(node, legs: list[tuple[float, float, float]] = LEGS) -> None:
    """Drive ``legs`` with cmd/twist at 20 Hz, stop, and wait for the wheels to rest and the last samples."""
    twist = node.publisher(keys.TWIST)
    for v, w, seconds in legs:
        for _ in range(round(seconds / 0.05)):
            twist.put(m.Twist(v=v, w=w))
            await asyncio.sleep(0.05)
    node.publisher(keys.STOP).put(m.Stop())
    await asyncio.sleep(1.0)


def check_exits(procs) -> None:
    """Every process still ran; ours (after sim and hwbridge, which the fixture stops) end cleanly on SIGINT."""
    for proc in procs:
        assert proc.alive(), proc.output
    for proc in procs[2:]:
        assert proc.stop() == 0, proc.output


def at(truth: list[m.Truth], stamp: int) -> m.Truth:
    """The true pose at ``stamp``, interpolated between the 50 Hz truth samples."""
    stamps = [t.stamp for t in truth]
    i = min(max(bisect.bisect_left(stamps, stamp), 1), len(truth) - 1)
    a, b = truth[i - 1], truth[i]
    f = min(max((stamp - a.stamp) / (b.stamp - a.stamp), 0.0), 1.0) if b.stamp > a.stamp else 1.0
    return m.Truth(stamp=stamp, x=a.x + f * (b.x - a.x), y=a.y + f * (b.y - a.y),
                   theta=wrap_angle(a.theta + f * wrap_angle(b.theta - a.theta)))


def error(est, t: m.Truth) -> tuple[float, float]:
    return math.hypot(est.x - t.x, est.y - t.y), abs(wrap_angle(est.theta - t.theta))


SKEW_NS = 40_000_000
"""Stamps of different processes (hwbridge's encoder read over the serial link, the simulator's truth)
may disagree by some ms on a loaded machine; turning at 1.5 rad/s, 20 ms is 1.7 degrees. An estimate is
compared with the true path within +-40 ms of its stamp: that checks *where* it puts the robot, not the
machine's scheduling."""


def error_near(est, truth: list[m.Truth]) -> tuple[float, float]:
    """Smallest position and heading error against the true path within SKEW_NS of the estimate's stamp."""
    near = [at(truth, est.stamp + d) for d in range(-SKEW_NS, SKEW_NS + 1, SKEW_NS // 8)]
    return min(error(est, t)[0] for t in near), min(error(est, t)[1] for t in near)


async def test_odometry_follows_the_simulated_robot_without_slip(make_robot) -> None:
    # ideal: the subject is odometry's integration of exact wheels (the realistic ones slip in starts and
    # turns whatever `slip` says: test_localizer_tracks_the_simulated_robot_with_slip drives those)
    robot = make_robot('[sim]\nprofile = "ideal"\nseed = 3\nslip = 0.0\nencoder_noise = 0.0\n')
    truth, odom, _, _ = await drive_square(robot, with_camera=False)
    final_pos, final_heading = error(odom[-1], truth[-1])
    moved = sum(math.hypot(b.x - a.x, b.y - a.y) for a, b in itertools.pairwise(truth))
    print(f"\nno slip, {moved:.2f} m: odometry final error {final_pos * 100:.2f} cm "
          f"{math.degrees(final_heading):.2f} deg")
    assert moved > 1.5
    assert final_pos < 0.01 and final_heading < math.radians(1.0)


async def test_localizer_tracks_the_simulated_robot_with_slip(make_robot) -> None:
    robot = make_robot("[sim]\nseed = 5\nslip = 0.1\nencoder_noise = 0.02\n\n"
                       "[localizer]\ninitial_x = 0.0\ninitial_y = 0.0\ninitial_theta = 0.0\n"
                       "initial_sigma_xy = 0.01\ninitial_sigma_theta = 0.02\n")
    truth, odom, loc, camera = await drive_square(robot, with_camera=True)
    moving = [e for e in loc if truth[0].stamp < e.stamp <= truth[-1].stamp]
    errors = [error_near(e, truth) for e in moving]
    worst_pos = max(p for p, _ in errors)
    worst_heading = max(h for _, h in errors)
    exact = [error(e, at(truth, e.stamp)) for e in moving]
    odo_pos, odo_heading = error(odom[-1], truth[-1])
    print(f"\nslip 0.1: {len(moving)} loc/pose, {camera.sightings} sightings; localizer max error "
          f"{worst_pos * 100:.2f} cm {math.degrees(worst_heading):.2f} deg; "
          f"odometry final {odo_pos * 100:.2f} cm {math.degrees(odo_heading):.2f} deg; "
          f"(at the exact stamps: {max(p for p, _ in exact) * 100:.2f} cm "
          f"{math.degrees(max(h for _, h in exact)):.2f} deg)")
    assert len(moving) > 100 and camera.sightings > 200
    assert worst_pos < 0.05
    assert worst_heading < math.radians(3.0)
