"""The client gives a student program SLAM's estimate and the map maker's map (a real bus). ~10 s."""

from __future__ import annotations

import asyncio
import time

from conftest import wait_for

from icefloe.client import AsyncRobot
from icefloe.schemas import keys
from icefloe.schemas import messages as m


async def test_client_reads_slam_pose_slam_map_and_the_landmark_map(robot) -> None:
    lm = [m.MapLandmark(id=3, x=1.0, y=2.0, covariance=[1e-4, 0.0, 0.0, 1e-4])]
    async with robot.node("tester") as node, AsyncRobot(config=robot.config) as r:
        assert r.slam_pose is None and r.slam_map is None and r.landmark_map is None
        pubs = [node.publisher(t) for t in (keys.SLAM_POSE, keys.SLAM_MAP, keys.MAP_LANDMARKS)]

        async def publish() -> None:
            while True:
                stamp = time.time_ns()
                pubs[0].put(m.PoseEstimate(stamp=stamp, x=0.5, y=0.0, theta=0.1, covariance=[0.0] * 9))
                pubs[1].put(m.LandmarkMap(stamp=stamp, landmarks=lm))
                pubs[2].put(m.LandmarkMap(stamp=stamp, landmarks=lm))
                await asyncio.sleep(0.1)

        task = asyncio.create_task(publish())
        await r.ready("slam/pose", "slam/map", "map/landmarks", timeout=30)
        await wait_for(lambda: r.slam_pose and r.slam_map and r.landmark_map, timeout=10)
        task.cancel()
        assert r.slam_pose.x == 0.5 and r.slam_map.landmarks[0].id == 3 and r.landmark_map.landmarks[0].x == 1.0
