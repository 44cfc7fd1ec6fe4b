"""The Robotics Toolbox's own EKF-SLAM on the robot's live data (needs ``pip install "icefloe[rtb]"``).

    python examples/rtb_slam.py                                 # the simulated robot (camera running)
    python examples/rtb_slam.py --robot penguin1 --connect tcp/10.0.0.5:7447

The robot drives a small square while this program collects its odometry (``odom/pose``) and
the camera's ArUco sightings (``camera/landmarks``); the toolbox's `EKF`, given a vehicle and a
sensor but no map, does SLAM on them, exactly as in the book's notebooks, with the toolbox's
simulation replaced by the robot (icefloe/rtb.py). It prints the map it made, and how far it is
from the world's true markers after alignment (what `icefloe score map` measures).
"""

from __future__ import annotations

import argparse
import asyncio
import math

import numpy as np
from roboticstoolbox import EKF

from icefloe import rtb
from icefloe.client import AsyncRobot, add_robot_arguments, robot_arguments
from icefloe.schemas import keys
from icefloe.score.maths import score_map
from icefloe.worldmap import load_world

V = np.diag([0.01**2, math.radians(1.0) ** 2])
"""Odometry noise per EKF step, (dd m, dth rad)^2: the toolbox's V."""
W = np.diag([0.03**2, 0.02**2])
"""Sighting noise, (range m, bearing rad)^2: the toolbox's W."""


async def collect(robot: AsyncRobot, feed: rtb.Feed, side: float) -> None:
    """Drive a square of ``side`` m (by time), putting odometry and sightings into ``feed`` meanwhile."""

    async def listen(topic: keys.Topic) -> None:
        async for msg in robot.node.subscribe(topic, latest=False, maxsize=1000):
            feed.add(msg)

    tasks = [asyncio.create_task(listen(t)) for t in (keys.ODOM_POSE, keys.LANDMARKS)]
    await robot.ready("odom/pose", "camera/landmarks", timeout=60)
    for _ in range(4):
        await robot.drive(0.15, 0.0, duration=side / 0.15)
        await robot.drive(0.0, 1.0, duration=math.pi / 2)
    await robot.stop()
    await asyncio.sleep(0.5)
    for task in tasks:
        task.cancel()


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_robot_arguments(parser)
    parser.add_argument("--side", type=float, default=0.4, help="side of the square driven, m")
    parser.add_argument("--world", default="lab", help="the world whose true markers the map is scored against")
    args = parser.parse_args()
    feed = rtb.Feed(holdback=0)
    async with AsyncRobot(**robot_arguments(args)) as robot:
        await collect(robot, feed, args.side)
    print(f"collected {len(feed)} steps")

    vehicle = rtb.Vehicle(feed, V, dt=0.05)
    sensor = rtb.Sensor(vehicle, None, W)  # no map: the EKF estimates it (SLAM)
    ekf = EKF(robot=(vehicle, V), sensor=(sensor, W), P0=np.diag([1e-4, 1e-4, 1e-4]), animate=False)
    ekf.init()
    while len(feed):
        ekf.step()

    estimate = {i: tuple(ekf.landmark_x(i)) for i in sorted(ekf.landmarks)}
    for i, (x, y) in estimate.items():
        print(f"landmark {i}: x {x:6.3f} m  y {y:6.3f} m")
    x, y, th = ekf.x_est[:3]
    print(f"robot at x {x:.3f} m, y {y:.3f} m, theta {math.degrees(th):.1f} deg (SLAM's frame: where it started)")
    truth = {mk.id: (mk.x, mk.y) for mk in load_world(args.world).markers}
    if len(set(estimate) & set(truth)) >= 2:
        score = score_map(estimate, truth)
        print(f"map RMSE after alignment: {score.rmse * 100:.2f} cm over {len(score.errors)} markers")


if __name__ == "__main__":
    asyncio.run(main())
