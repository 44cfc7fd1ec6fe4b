"""The Robotics Toolbox's own EKF on the simulated robot's messages, through icefloe.rtb.

Real processes (sim + hwbridge + odometry) drive a tour while the test plays the camera (as
test_slam_sim.py); the robot's odom/pose, camera/landmarks and sim/truth go into a `rtb.Feed`,
and the toolbox's EKF does map-based localization, map making and SLAM on them, checked against
the truth. Skipped when the toolbox is not installed (``pip install "icefloe[rtb]"``). ~35 s alone
on this machine.
"""

from __future__ import annotations

import asyncio
import math
import random

import numpy as np
import pytest
from conftest import wait_for
from test_localizer_sim import drive_legs

rtb_toolbox = pytest.importorskip("roboticstoolbox", reason="the Robotics Toolbox is not installed: "
                                  'pip install "icefloe[rtb]"')

from icefloe import rtb  # noqa: E402
from icefloe.angles import wrap_angle  # noqa: E402
from icefloe.grid import from_world  # noqa: E402
from icefloe.schemas import keys  # noqa: E402
from icefloe.schemas import messages as m  # noqa: E402
from icefloe.score.maths import score_map  # noqa: E402
from icefloe.testing import TruthCamera, play_camera  # noqa: E402
from icefloe.worldmap import load_world  # noqa: E402

WORLD = load_world("lab")
TRUE = {mk.id: (mk.x, mk.y) for mk in WORLD.markers}
TOUR = [(0.2, 0.0, 4.0), (0.0, 1.5, math.pi / 3)] * 4
V = np.diag([0.01**2, math.radians(1.0) ** 2])
"""Odometry noise per step (dd m, dth rad)^2, as the toolbox wants it."""
W = np.diag([0.03**2, 0.02**2])
"""Sighting noise (range m, bearing rad)^2."""


async def recorded_tour(robot) -> list:
    procs = [robot.start(s) for s in ("sim", "hwbridge", "odometry")]
    msgs: list = []
    async with robot.node("tester") as node:
        camera = TruthCamera(robot.config, random.Random(5))

        def seen(truth: m.Truth, frame: m.Landmarks | None) -> None:
            msgs.append(truth)
            if frame is not None:
                msgs.append(frame)

        async def odom() -> None:
            async for p in node.subscribe(keys.ODOM_POSE, latest=False):
                msgs.append(p)

        tasks = [asyncio.create_task(play_camera(node, camera, on_truth=seen)), asyncio.create_task(odom())]
        await wait_for(lambda: any(isinstance(x, m.Pose) for x in msgs) and len(msgs) > 20, timeout=90)
        await drive_legs(node, TOUR)
        for task in tasks:
            task.cancel()
    for proc in procs:
        assert proc.alive(), proc.output
    return msgs


def ekf(msgs: list, *, localize: bool = False, known_pose: bool = False):
    """The toolbox's EKF over the messages; returns it after every tick has been used."""
    from roboticstoolbox import EKF

    feed = rtb.Feed(holdback=0).extend(x for x in msgs if known_pose or not isinstance(x, m.Truth))
    first = next(x for x in msgs if isinstance(x, m.Truth))
    vehicle = rtb.Vehicle(feed, V, x0=(first.x, first.y, first.theta), dt=0.02)
    sensor = rtb.Sensor(vehicle, rtb.landmark_map(WORLD) if localize else None, W)
    if known_pose:  # map making: the vehicle's pose is the truth, the state is the map alone
        f = EKF(robot=(vehicle, None), sensor=(sensor, W), animate=False, history=False)
    else:
        f = EKF(robot=(vehicle, V), sensor=(sensor, W), map=sensor.map if localize else None,
                P0=np.diag([1e-4, 1e-4, 1e-4]), x0=(first.x, first.y, first.theta), animate=False, history=False)
    f.init()
    while len(feed):
        f.step()
    return f


@pytest.fixture(scope="module")
def tour_messages(tmp_path_factory):
    from conftest import Robot

    robot = Robot(tmp_path_factory.mktemp("rtb"), "[sim]\nseed = 6\nslip = 0.05\nencoder_noise = 0.01\n")
    try:
        yield asyncio.run(recorded_tour(robot))
    finally:
        robot.close()


def final_truth(msgs) -> m.Truth:
    return [x for x in msgs if isinstance(x, m.Truth)][-1]


@pytest.mark.timeout(600)
def test_toolbox_ekf_localization_on_the_robot(tour_messages) -> None:
    f = ekf(tour_messages, localize=True)
    x, y, th = f.x_est[:3]
    t = final_truth(tour_messages)
    err, head = math.hypot(x - t.x, y - t.y), abs(wrap_angle(th - t.theta))
    print(f"\ntoolbox EKF localization: final {err * 100:.2f} cm {math.degrees(head):.2f} deg")
    assert err < 0.05 and head < math.radians(3)


@pytest.mark.timeout(600)
def test_toolbox_map_making_and_slam_on_the_robot(tour_messages) -> None:
    made = ekf(tour_messages, known_pose=True)
    made_score = score_map({i: tuple(made.landmark_x(i)) for i in made.landmarks}, TRUE)
    slam = ekf(tour_messages)
    slam_score = score_map({i: tuple(slam.landmark_x(i)) for i in slam.landmarks}, TRUE)
    x, y = slam.x_est[:2]
    t = final_truth(tour_messages)
    err = math.hypot(x - t.x, y - t.y)
    print(f"\ntoolbox map making: {len(made_score.errors)} landmarks, RMSE {made_score.rmse * 100:.2f} cm; "
          f"SLAM: RMSE {slam_score.rmse * 100:.2f} cm, final pose {err * 100:.2f} cm")
    assert len(made_score.errors) >= 4 and made_score.rmse <= 0.05 and made_score.rmse_raw <= 0.05
    assert len(slam_score.errors) >= 4 and slam_score.rmse <= 0.05 and err <= 0.05
    assert slam.P_est.shape == (3 + 2 * len(slam.landmarks),) * 2


def test_feed_orders_messages_bounds_memory_and_ignores_odd_ids() -> None:
    feed = rtb.Feed(holdback=0.1)
    feed.add(m.Landmarks(stamp=2_000_000_000, landmarks=[m.Landmark(id=3, range=1.0, bearing=0.1),
                                                         m.Landmark(id=5000, range=1.0, bearing=0.0)]))
    feed.add(m.Pose(stamp=1_000_000_000, x=0.0, y=0.0, theta=0.0))
    feed.add(m.Pose(stamp=1_900_000_000, x=0.1, y=0.0, theta=0.2))
    assert feed.next().sighting is None  # the frame is within the holdback of the newest message
    feed.add(m.Pose(stamp=2_200_000_000, x=0.2, y=0.0, theta=0.2))
    first = feed.next()
    assert first.odo == pytest.approx((0.1, 0.2)) and first.sighting == (1.0, 0.1, 3)
    vehicle = rtb.Vehicle(rtb.Feed(), V)
    vehicle.tick = feed.next()
    assert rtb.Sensor(vehicle, None, W).reading() == (None, None)  # id 5000 > MAX_ID
    flood = rtb.Feed()
    for k in range(rtb.MAX_PENDING + 10):
        flood.add(m.Pose(stamp=k, x=0.0, y=0.0, theta=0.0))
    assert len(flood) == rtb.MAX_PENDING and flood.dropped == 10


def test_the_occupancy_grid_is_the_planners_map() -> None:
    from roboticstoolbox import DistanceTransformPlanner

    grid = from_world(WORLD, 0.05)
    occ = rtb.occupancy_grid(grid)
    assert occ.grid.shape == grid.cells.shape
    planner = DistanceTransformPlanner(occ)
    planner.plan(goal=(1.2, 1.2))  # world coordinates, m: the toolbox converts with the grid's origin
    path = planner.query(start=(0.0, 0.0))
    cells = [grid.cell(x, y) for x, y in path]
    assert len(path) > 10 and all(not grid.cells[r, c] for r, c in cells)
    assert math.dist(path[0], (0.0, 0.0)) < 0.05 and math.dist(path[-1], (1.2, 1.2)) < 0.05
