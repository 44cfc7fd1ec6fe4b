"""The grid, the planner and the follower as real processes on the simulated lab, against its truth.

The simulator, hwbridge and the three services run as processes over a real router; the test
asks ``map/grid`` and ``nav/plan`` as a student's program would, publishes the plan on
``nav/path`` and watches ``sim/truth``: the robot drives the path, hits nothing, and stops at its
end. The follower steers from the simulator's truth here (``follower.pose = "sim/truth"``), so
what is measured is the follower, not the localizer (bench/planner.py measures both).
"""

from __future__ import annotations

import asyncio
import itertools
import math

import numpy as np
import pytest
from conftest import wait_for

from icefloe.grid import of_robot
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.follower.pursuit import project

pytestmark = pytest.mark.slow

FOLLOWER = '[follower]\npose = "sim/truth"\n'


def distance_to_path(path: list[tuple[float, float]], x: float, y: float) -> float:
    return min(project(a, b, (x, y))[1] for a, b in itertools.pairwise(path))


async def ask(node, topic, request, timeout: float = 30.0):
    """A query, asked again while its service is not up yet (a loaded machine starts them slowly)."""
    deadline = asyncio.get_running_loop().time() + timeout
    while True:
        try:
            return await node.query(topic, request, timeout=10.0)
        except Exception:
            if asyncio.get_running_loop().time() > deadline:
                raise
            await asyncio.sleep(0.5)


async def test_plan_then_follow_drives_the_path_and_stops_at_its_end(make_robot) -> None:
    robot = make_robot(FOLLOWER)
    for service in ("sim", "hwbridge", "grid", "planner", "follower"):
        robot.start(service)
    truth: list[m.Truth] = []
    statuses: list[m.FollowStatus] = []
    async with robot.node("tester") as node:
        grid = await ask(node, keys.MAP_GRID, m.GridRequest())
        mine = of_robot(robot.config)
        assert (grid.height, grid.width) == mine.shape and grid.cells == mine.cells.tobytes()
        assert grid.world == "lab" and grid.resolution == 0.02 and grid.inflation == 0.0

        # from the start pose (the origin, facing +x) round the crate to the far corner
        goal = (-1.5, -1.5)
        plan = await ask(node, keys.PLAN, m.PlanRequest(start_x=0.0, start_y=0.0, goal_x=goal[0], goal_y=goal[1]))
        assert plan.ok, plan.reason
        assert plan.path[0] == (0.0, 0.0) and plan.path[-1] == goal and plan.length > math.dist((0, 0), goal)

        async def watch(topic, into) -> None:
            async for msg in node.subscribe(topic, latest=False):
                into.append(msg)

        tasks = [asyncio.create_task(watch(keys.TRUTH, truth)), asyncio.create_task(watch(keys.NAV_STATUS, statuses))]
        await wait_for(lambda: truth and statuses, timeout=30)
        node.publisher(keys.NAV_PATH).put(node.command(m.NavPath, points=plan.path))
        await wait_for(lambda: any(s.state == "arrived" for s in statuses), timeout=120)
        await wait_for(lambda: len(truth) > 5 and truth[-1].x == truth[-5].x and truth[-1].y == truth[-5].y,
                       timeout=10)
        for task in tasks:
            task.cancel()

    end = truth[-1]
    assert math.dist((end.x, end.y), goal) < 0.05, (end.x, end.y)
    driven = [t for t in truth if math.hypot(t.x, t.y) > 0.01]
    errors = [distance_to_path(plan.path, t.x, t.y) for t in driven]
    assert max(errors) < 0.1 and float(np.median(errors)) < 0.03, (max(errors), np.median(errors))
    assert not any(t.collided for t in truth) and end.collisions == 0
