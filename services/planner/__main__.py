"""The reference planner: answers ``nav/plan`` (start, goal -> a path, or why there is none).

    python -m icefloe.services.planner --config deploy/robots/sim.toml
    icefloe query nav/plan '{"start_x": 0, "start_y": 0, "goal_x": 1.5, "goal_y": -1.6}'

It plans on the grid of the robot's world (`icefloe.grid.of_robot`: the grid ``map/grid``
serves) grown by ``geometry.radius + planner.clearance``, with A* (`astar.py`: the maths, one
small module). A student's own planner replaces it by answering the same key
(docs/planning.md). One plan is computed at a time, in a worker thread (the event loop keeps
answering); ``planner.max_waiting`` more may wait, and any beyond that are answered "busy" at
once, so a flood of queries costs neither memory nor more than one CPU.
"""

from __future__ import annotations

import asyncio
import time

from icefloe.config import RobotConfig
from icefloe.errors import BadPayload
from icefloe.grid import Grid, of_robot
from icefloe.runtime import Node, run
from icefloe.schemas import keys
from icefloe.schemas import messages as m

from .astar import NoPath, length, plan


def answer_plan(grid: Grid, request: m.PlanRequest) -> m.Plan:
    """The `Plan` for one request (blocking: run it in a thread)."""
    t0 = time.perf_counter()
    start, goal = (request.start_x, request.start_y), (request.goal_x, request.goal_y)
    try:
        points, expanded = plan(grid, start, goal)
    except NoPath as exc:
        return m.Plan(stamp=time.time_ns(), ok=False, reason=f"no path: {exc}", seconds=time.perf_counter() - t0)
    return m.Plan(stamp=time.time_ns(), ok=True, path=[m.Waypoint(x, y) for x, y in points], length=length(points),
                  expanded=expanded, seconds=time.perf_counter() - t0)


async def main(config: RobotConfig) -> None:
    inflation = config.geometry.radius + config.planner.clearance
    grid = of_robot(config).inflate(inflation)
    one_at_a_time = asyncio.Lock()
    in_hand = 0  # the plan being made and those waiting for it

    async with Node("planner", config) as node:

        async def answer(request: m.PlanRequest) -> m.Plan:
            nonlocal in_hand
            if in_hand > config.planner.max_waiting:
                raise BadPayload(f"{node.key(keys.PLAN)}: busy (one plan being made, {in_hand - 1} waiting); "
                                 "ask again later")
            in_hand += 1
            try:
                async with one_at_a_time:
                    result = await asyncio.to_thread(answer_plan, grid, request)
            finally:
                in_hand -= 1
            node.limited.info("plan", "plan (%.2f, %.2f) -> (%.2f, %.2f): %s in %.3f s", request.start_x,
                              request.start_y, request.goal_x, request.goal_y,
                              f"{len(result.path)} points, {result.length:.2f} m" if result.ok else result.reason,
                              result.seconds)
            return result

        node.queryable(keys.PLAN, answer)
        rows, cols = grid.shape
        node.log.info("serving %s: world %s, %d x %d cells of %.3f m, obstacles grown by %.3f m",
                      node.key(keys.PLAN), grid.world, cols, rows, grid.resolution, inflation)
        await asyncio.Event().wait()  # until SIGINT/SIGTERM cancels us


if __name__ == "__main__":
    run(main)
