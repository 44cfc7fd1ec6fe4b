"""The planner and the follower on the simulated lab: planning time, tracking error, CPU.

    .venv/bin/python bench/planner.py [--pose loc/pose|sim/truth] [--repeat 5]

1. In this process: the time to plan across the lab at 2 cm (A*, `services/planner/astar.py`,
   from the north-west corner behind the partition to the south-east one), next to two
   references measured in the same run: the grid's size, and a breadth-first flood of every
   free cell from the start (what a planner with no heuristic and no costs would visit).
2. With real processes (`icefloe up` with sim, hwbridge, odometry, camera, localizer, planner
   and follower): a plan from the start pose round the partition, driven by the follower from
   the pose on ``--pose`` (default the localizer's, as on a real robot); against the simulator's
   truth: the cross-track error along the path (p50, max), the final position error, collisions;
   and the CPU of the planner and follower over the drive, next to the simulator's.
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import math
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections import deque
from pathlib import Path

from common import cpu_seconds, free_port, robot_config
from stack_cpu import children

from icefloe import config as config_mod
from icefloe.grid import FREE, from_world
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.follower.pursuit import project
from icefloe.services.planner.astar import length, plan
from icefloe.worldmap import load_world

ACROSS = ((-1.5, 1.3), (1.5, -1.6))
"""Start and goal of the timed plan: corner to corner, round the partition, crate and bench."""
DRIVE_GOAL = (-1.5, 1.3)
"""Where the driven path goes from the start pose (the origin): round the partition's end."""


def bfs_cells(free, start: tuple[int, int]) -> int:
    """Cells a 4-connected breadth-first flood reaches from ``start`` (the reference)."""
    rows, cols = free.shape
    seen = bytearray(rows * cols)
    flat = free.ravel().tolist()
    queue = deque([start[0] * cols + start[1]])
    seen[queue[0]] = 1
    while queue:
        cell = queue.popleft()
        r, c = divmod(cell, cols)
        for n, ok in ((cell - cols, r > 0), (cell + cols, r < rows - 1), (cell - 1, c > 0), (cell + 1, c < cols - 1)):
            if ok and flat[n] and not seen[n]:
                seen[n] = 1
                queue.append(n)
    return sum(seen)


def planning(repeat: int) -> None:
    t0 = time.perf_counter()
    grid = from_world(load_world("lab"), 0.02)
    made = time.perf_counter() - t0
    t0 = time.perf_counter()
    inflated = grid.inflate(0.1 + 0.05)
    grown = time.perf_counter() - t0
    times, cpu, expanded, points = [], [], 0, []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        points, expanded = plan(inflated, *ACROSS)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    free = inflated.cells == FREE
    bfs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        reached = bfs_cells(free, inflated.cell(*ACROSS[0]))
        bfs.append(time.perf_counter() - t0)
    rows, cols = grid.shape
    print(f"grid: lab at 0.02 m: {cols} x {rows} = {rows * cols} cells ({int(free.sum())} free after growing by "
          f"0.15 m); made in {made * 1e3:.0f} ms, grown in {grown * 1e3:.0f} ms")
    print(f"plan across the lab {ACROSS[0]} -> {ACROSS[1]}: median {statistics.median(times) * 1e3:.0f} ms "
          f"(min {min(times) * 1e3:.0f}, max {max(times) * 1e3:.0f}; CPU {statistics.median(cpu) * 1e3:.0f} ms) "
          f"over {repeat}; {expanded} cells expanded, "
          f"{len(points)} points, {length(points):.2f} m (straight line {math.dist(*ACROSS):.2f} m)")
    print(f"reference: breadth-first flood of the free cells from the start: {reached} cells in "
          f"median {statistics.median(bfs) * 1e3:.0f} ms")


def distance_to_path(path: list[m.Waypoint], x: float, y: float) -> float:
    return min(project((a.x, a.y), (b.x, b.y), (x, y))[1] for a, b in itertools.pairwise(path))


async def drive(config: config_mod.RobotConfig, path: Path) -> None:
    truth: list[m.Truth] = []
    statuses: list[m.FollowStatus] = []
    async with Node("bench", config) as node:
        async def watch(topic, into) -> None:  # type: ignore[no-untyped-def]
            async for msg in node.subscribe(topic, latest=False):
                into.append(msg)

        tasks = [asyncio.create_task(watch(keys.TRUTH, truth)), asyncio.create_task(watch(keys.NAV_STATUS, statuses))]
        deadline = time.monotonic() + 120
        while True:
            try:
                result = await node.query(keys.PLAN, m.PlanRequest(start_x=0.0, start_y=0.0, goal_x=DRIVE_GOAL[0],
                                                                    goal_y=DRIVE_GOAL[1]), timeout=10)
                break
            except Exception:
                if time.monotonic() > deadline:
                    raise
                await asyncio.sleep(1.0)
        while not (truth and statuses):
            await asyncio.sleep(0.1)
        await asyncio.sleep(5.0)  # the localizer settles on the markers it sees
        procs = children(path)
        cpu0 = {n: sum(cpu_seconds(p) for p in pids) for n, pids in procs.items()}
        t0 = time.monotonic()
        start = len(truth)
        node.publisher(keys.NAV_PATH).put(node.command(m.NavPath, points=result.path))
        while not any(s.state in ("arrived", "stopped") for s in statuses) and time.monotonic() - t0 < 180:
            await asyncio.sleep(0.1)
        wall = time.monotonic() - t0
        cpu = {n: 100 * (sum(cpu_seconds(p) for p in pids) - cpu0[n]) / wall for n, pids in procs.items()}
        await asyncio.sleep(1.0)
        # the planner busy: plans across the lab, one after another, as a class of students might ask
        planner0, t1 = sum(cpu_seconds(p) for p in procs["planner"]), time.monotonic()
        asked = [await node.query(keys.PLAN, m.PlanRequest(start_x=ACROSS[0][0], start_y=ACROSS[0][1],
                                                            goal_x=ACROSS[1][0], goal_y=ACROSS[1][1]), timeout=30)
                 for _ in range(5)]
        busy_cpu = (sum(cpu_seconds(p) for p in procs["planner"]) - planner0) / (time.monotonic() - t1)
        for task in tasks:
            task.cancel()
    driven = truth[start:]
    errors = sorted(distance_to_path(result.path, t.x, t.y) for t in driven)
    end = truth[-1]
    print(f"drive: plan (0, 0) -> {DRIVE_GOAL}: {len(result.path)} points, {result.length:.2f} m, planned in "
          f"{result.seconds * 1e3:.0f} ms by the service; follower: {statuses[-1].state} after {wall:.1f} s")
    print(f"cross-track error (truth to path), {len(errors)} samples: p50 {errors[len(errors) // 2] * 100:.1f} cm, "
          f"max {errors[-1] * 100:.1f} cm; final position error {math.dist((end.x, end.y), DRIVE_GOAL) * 100:.1f} cm;"
          f" collisions {end.collisions}")
    print(f"CPU over the drive, % of one core ({os.cpu_count()} cores): "
          + ", ".join(f"{n} {cpu[n]:.1f} %" for n in ("planner", "follower", "sim", "localizer", "camera") if n in cpu)
          + " (the simulator is the reference)")
    print(f"planner answering 5 plans across the lab back to back: {100 * busy_cpu:.0f} % of one core, "
          f"median {statistics.median(r.seconds for r in asked) * 1e3:.0f} ms a plan (its own figure)")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--pose", choices=("loc/pose", "sim/truth"), default="loc/pose",
                   help="the pose the follower steers from (default: the localizer's)")
    p.add_argument("--repeat", type=int, default=5, help="plans timed (default 5)")
    args = p.parse_args()
    planning(args.repeat)
    services = '["sim", "hwbridge", "odometry", "camera", "localizer", "planner", "follower"]'
    path = robot_config(Path(tempfile.mkdtemp()), "planbench",
                        f'services = {services}\n[webapi]\nport = {free_port()}\n'
                        f'[follower]\npose = "{args.pose}"\n')
    config = config_mod.load(path)
    up = subprocess.Popen([sys.executable, "-m", "icefloe.cli", "up", str(path), "--no-viz"],
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        time.sleep(10.0)
        print(f"follower steering from {args.pose}:")
        asyncio.run(drive(config, path))
    finally:
        up.send_signal(signal.SIGINT)
        up.wait(60)


if __name__ == "__main__":
    main()
