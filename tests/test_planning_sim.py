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

import msgspec
import numpy as np
import pytest
from conftest import wait_for

from icefloe.errors import BadPayload
from icefloe.grid import of_robot
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.follower.pursuit import project

pytestmark = pytest.mark.slow

FOLLOWER = '[follower]\npose = "sim/truth"\n'


def distance_to_path(path: list[m.Waypoint], x: float, y: float) -> float:
    return min(project((a.x, a.y), (b.x, b.y), (x, y))[1] for a, b in itertools.pairwise(path))


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


@pytest.mark.timeout(300)  # the drive itself takes about a minute; a busy machine slows the loop
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
        grown = await ask(node, keys.MAP_GRID, m.GridRequest(inflation=0.15))
        assert grown.cells == mine.inflate(0.15).cells.tobytes() and grown.inflation == 0.15

        # from the start pose (the origin, facing +x) round the crate to the far corner
        goal = (-1.5, -1.5)
        plan = await ask(node, keys.PLAN, m.PlanRequest(start_x=0.0, start_y=0.0, goal_x=goal[0], goal_y=goal[1]))
        assert plan.ok, plan.reason
        assert plan.path[0] == m.Waypoint(0.0, 0.0) and plan.path[-1] == m.Waypoint(*goal)
        assert plan.length > math.dist((0, 0), goal)

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


async def test_hostile_plans_and_paths_and_a_stop_that_wins(make_robot) -> None:
    """On one robot: a goal in a wall, a flood of plan queries, a path with NaN, a stop while
    following, a path issued before a stop that arrives after it. The robot's truth decides."""
    robot = make_robot(FOLLOWER + "[planner]\nmax_waiting = 2\n")
    procs = {s: robot.start(s) for s in ("sim", "hwbridge", "planner", "follower")}
    truth: list[m.Truth] = []
    statuses: list[m.FollowStatus] = []
    async with robot.node("tester") as node:
        async def watch(topic, into) -> None:
            async for msg in node.subscribe(topic, latest=False):
                into.append(msg)

        tasks = [asyncio.create_task(watch(keys.TRUTH, truth)), asyncio.create_task(watch(keys.NAV_STATUS, statuses))]

        # a goal inside the crate, and one outside the room's map: no path, and why
        plan = await ask(node, keys.PLAN, m.PlanRequest(start_x=0, start_y=0, goal_x=-0.9, goal_y=-0.9))
        assert not plan.ok and "the goal (-0.900, -0.900) is inside an obstacle" in plan.reason and not plan.path
        plan = await ask(node, keys.PLAN, m.PlanRequest(start_x=0, start_y=0, goal_x=9, goal_y=0))
        assert not plan.ok and "outside the map" in plan.reason

        # a flood: 40 queries at once; one is planned at a time, 2 wait, the rest are "busy" at once
        far = m.PlanRequest(start_x=-1.5, start_y=1.3, goal_x=1.5, goal_y=-1.6)
        results = await asyncio.gather(*(node.query(keys.PLAN, far, timeout=60) for _ in range(40)),
                                       return_exceptions=True)
        busy = [r for r in results if isinstance(r, BadPayload) and "busy" in str(r)]
        planned = [r for r in results if isinstance(r, m.Plan) and r.ok]
        assert len(busy) + len(planned) == 40 and planned and busy, results
        assert (await ask(node, keys.PLAN, far)).ok and procs["planner"].alive()

        # a path with NaN in it (MessagePack carries NaN; JSON cannot): dropped, named, nothing moves
        await wait_for(lambda: truth and statuses, timeout=30)
        nan = {"points": [{"x": 0.0, "y": 0.0}, {"x": math.nan, "y": 1.0}]}
        node.session.put(node.key(keys.NAV_PATH), msgspec.msgpack.encode(nan), encoding="application/msgpack")
        await wait_for(lambda: "point 1 is not finite" in procs["follower"].output, timeout=20)
        assert statuses[-1].state == "idle" and math.hypot(truth[-1].x, truth[-1].y) < 1e-3

        # a stop while following: the wheels stop, the follower gives the path up, nothing restarts them
        path = node.publisher(keys.NAV_PATH)
        path.put(node.command(m.NavPath, points=[m.Waypoint(0.0, 0.0), m.Waypoint(1.0, 0.0)]))
        await wait_for(lambda: truth[-1].x > 0.1, timeout=30)
        node.publisher(keys.STOP).put(node.command(m.Stop))
        await wait_for(lambda: statuses[-1].state == "stopped", timeout=10)
        assert statuses[-1].reason == "a stop on cmd/stop"
        await wait_for(lambda: len(truth) > 10 and truth[-1].x == truth[-10].x, timeout=10)
        stopped_at = truth[-1].x
        await asyncio.sleep(2.0)   # the follower's loop would have sent 40 twists by now
        assert truth[-1].x == stopped_at < 0.5

        # a path issued before a stop, arriving after it: refused, the robot stays
        old = node.command(m.NavPath, points=[m.Waypoint(stopped_at, 0.0), m.Waypoint(1.0, 0.0)])
        node.publisher(keys.STOP).put(node.command(m.Stop))
        await asyncio.sleep(0.2)
        path.put(old)
        await wait_for(lambda: statuses[-1].reason.startswith("path refused: issued before a stop"), timeout=10)
        await asyncio.sleep(1.0)
        assert truth[-1].x == stopped_at and statuses[-1].state == "stopped"
        for task in tasks:
            task.cancel()
    for name, proc in procs.items():
        assert proc.alive(), (name, proc.output)


MY_PLANNER = '''\
"""A student's planner: a straight line from start to goal, on the reference planner's key."""
import asyncio, time
from icefloe.runtime import Node, run
from icefloe.schemas import keys, messages as m

async def main(config):
    async def answer(r: m.PlanRequest) -> m.Plan:
        path = [m.Waypoint(r.start_x, r.start_y), m.Waypoint(r.goal_x, r.goal_y)]
        return m.Plan(stamp=time.time_ns(), ok=True, reason="mine", path=path)
    async with Node("my_planner", config) as node:
        node.queryable(keys.PLAN, answer)
        node.log.info("my planner is up")
        await asyncio.Event().wait()

if __name__ == "__main__":
    run(main)
'''


async def test_a_students_planner_replaces_the_reference_one_by_config(tmp_path) -> None:
    """`icefloe up` with a config whose services leave the reference planner out and run the
    student's in its place: the same key answers with the student's plan, and the reference
    follower drives it."""
    import subprocess
    import sys

    from conftest import robot_config, stop_up

    from icefloe import config as config_mod

    (tmp_path / "my_planner.py").write_text(MY_PLANNER)
    program = '[programs.my_planner]\ncommand = ["{python}", "my_planner.py"]\n'
    path = robot_config(tmp_path, "mine", f'services = ["sim", "hwbridge", "follower", "my_planner"]\n'
                                          f"{FOLLOWER}\n{program}")
    config = config_mod.load(path)
    up = subprocess.Popen([sys.executable, "-m", "icefloe.cli", "up", str(path)], stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, start_new_session=True, text=True)
    truth: list[m.Truth] = []
    try:
        from icefloe.runtime import Node

        async with Node("tester", config) as node:
            plan = await ask(node, keys.PLAN, m.PlanRequest(start_x=0, start_y=0, goal_x=0.4, goal_y=0.3), timeout=90)
            assert plan.reason == "mine" and plan.path == [m.Waypoint(0.0, 0.0), m.Waypoint(0.4, 0.3)]
            alive = await node.alive()
            assert not any(a.endswith("/planner") for a in alive) and any(a.endswith("/my_planner") for a in alive)

            async def watch() -> None:
                async for t in node.subscribe(keys.TRUTH, latest=False):
                    truth.append(t)

            task = asyncio.create_task(watch())
            await wait_for(lambda: truth, timeout=60)
            node.publisher(keys.NAV_PATH).put(node.command(m.NavPath, points=plan.path))
            await wait_for(lambda: math.dist((truth[-1].x, truth[-1].y), (0.4, 0.3)) < 0.05, timeout=60)
            task.cancel()
    finally:
        assert stop_up(up) == 0
        output = up.stdout.read()
    assert "my planner is up" in output, output
