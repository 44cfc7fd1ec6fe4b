"""Tests of example_service, in two layers as icefloe's own: the logic alone, then
the service on a real bus (a Zenoh router in this process).

    python -m pytest test_example_service.py
"""

from __future__ import annotations

import asyncio
import time

import pytest
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.testing import eventually, local_bus

import example_service as service


def pose(x: float, y: float = 0.0) -> m.Pose:
    return m.Pose(stamp=time.time_ns(), x=x, y=y, theta=0.0)


def test_a_step_is_the_distance_between_two_poses() -> None:
    assert service.step(pose(0.0), pose(0.3, 0.4)) == pytest.approx(0.5)


def test_the_service_publishes_the_distance_driven() -> None:
    asyncio.run(drive_and_watch())


async def drive_and_watch() -> None:
    async with local_bus() as config:
        running = asyncio.create_task(service.main(config))
        async with Node("tester", config) as node:
            distances = node.subscribe(service.DISTANCE, latest=False)
            poses = node.publisher(keys.ODOM_POSE)
            # Declarations take a moment to reach the router: send the start
            # until the service answers.
            await eventually(lambda: poses.put(pose(0.0)) or distances.pending())
            for x in (0.1, 0.25, 0.25, 0.0):  # forward 0.25 m, stand, back 0.25 m
                poses.put(pose(x))
            last = 0.0
            while last < 0.5 - 1e-9:
                last = (await asyncio.wait_for(anext(distances), 5.0)).metres
            assert last == pytest.approx(0.5)
        running.cancel()
