"""The grid service: the world's occupancy grid on the bus, so every program plans on one map.

    python -m icefloe.services.grid --config deploy/robots/sim.toml
    icefloe query map/grid '{"inflation": 0.12}'

It answers ``map/grid`` (`GridRequest` -> `OccupancyGrid`, read-only: anyone who may watch the
robot may ask) with the obstacles of ``planner.world`` (else ``localizer.world``) at
``planner.resolution``, grown by the ``inflation`` asked for (`icefloe.grid`). The same grid,
as a file: ``icefloe grid WORLD --out grid.png``.
"""

from __future__ import annotations

import asyncio
import time
from collections import OrderedDict

from icefloe.config import RobotConfig
from icefloe.grid import Grid, of_robot
from icefloe.runtime import Node, run
from icefloe.schemas import keys
from icefloe.schemas import messages as m

CACHED = 8
"""Inflated grids kept (a few robots' radii); the rest are made again when asked."""


def grid_message(grid: Grid) -> m.OccupancyGrid:
    rows, cols = grid.shape
    return m.OccupancyGrid(stamp=time.time_ns(), world=grid.world, resolution=grid.resolution,
                           origin_x=grid.origin_x, origin_y=grid.origin_y, width=cols, height=rows,
                           inflation=grid.inflation, cells=grid.cells.tobytes())


async def main(config: RobotConfig) -> None:
    grid = of_robot(config)
    answers: OrderedDict[float, m.OccupancyGrid] = OrderedDict()

    async def answer(request: m.GridRequest) -> m.OccupancyGrid:
        inflation = round(request.inflation, 4)
        if inflation not in answers:
            answers[inflation] = await asyncio.to_thread(lambda: grid_message(grid.inflate(inflation)))
            while len(answers) > CACHED:
                answers.popitem(last=False)
        answers.move_to_end(inflation)
        return answers[inflation]

    async with Node("grid", config) as node:
        node.queryable(keys.MAP_GRID, answer)
        rows, cols = grid.shape
        node.log.info("serving %s: world %s, %d x %d cells of %.3f m", node.key(keys.MAP_GRID), grid.world,
                      cols, rows, grid.resolution)
        await asyncio.Event().wait()  # until SIGINT/SIGTERM cancels us


if __name__ == "__main__":
    run(main)
