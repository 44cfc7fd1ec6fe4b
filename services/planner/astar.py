"""A* on an occupancy grid: the reference planner's maths, as a student would write it.

The robot is a point moving between the centres of free cells, to any of its 8 neighbours: a
straight step costs 1 cell, a diagonal one sqrt(2), and a diagonal step may not cut the corner
of an occupied cell. The grid is the world's obstacles grown by the robot's radius
(`icefloe.grid.Grid.inflate`), so a point path there is a safe path for the whole robot.

A* expands cells in the order of ``cost so far + h``, where ``h`` is the octile distance to the
goal: the exact cost on an empty 8-connected grid, so it never overestimates and the first
time the goal is taken from the queue its path is a shortest one. (With ``h = 0`` this is
Dijkstra's uniform-cost search; a distance-transform planner computes the same costs from the
goal outwards, for every cell at once.)

`shortcut` then drops the points a straight line can skip (while the line stays in free
cells): a path of a few corners, which a pure-pursuit follower drives smoothly.
"""

from __future__ import annotations

import heapq
import itertools
import math

import numpy as np

from icefloe.grid import FREE, Grid

SQRT2 = math.sqrt(2.0)
MOVES = ((0, 1, 1.0), (1, 0, 1.0), (0, -1, 1.0), (-1, 0, 1.0),
         (1, 1, SQRT2), (1, -1, SQRT2), (-1, 1, SQRT2), (-1, -1, SQRT2))
"""(row step, column step, cost in cells): the 8 neighbours."""


class NoPath(Exception):
    """There is no path; the message says why (a student's planner answers it as ``reason``)."""


def octile(a: tuple[int, int], b: tuple[int, int]) -> float:
    """Length of the shortest 8-connected path from cell a to cell b on an empty grid, cells."""
    dr, dc = abs(a[0] - b[0]), abs(a[1] - b[1])
    return max(dr, dc) + (SQRT2 - 1.0) * min(dr, dc)


def astar(free: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> tuple[list[tuple[int, int]], int]:
    """The shortest 8-connected path of free cells from ``start`` to ``goal`` (both (row, col),
    both free), as a list of cells, and the number of cells expanded. `NoPath` if there is none.

    ``free[row, col]`` is True for a free cell."""
    rows, cols = free.shape
    is_free = free.ravel().tolist()              # a flat list: much faster to index than NumPy
    came_from: dict[int, int] = {}
    cost = {start[0] * cols + start[1]: 0.0}
    target = goal[0] * cols + goal[1]
    queue = [(octile(start, goal), 0.0, start[0] * cols + start[1])]
    done = bytearray(rows * cols)                # 1 once a cell is expanded
    expanded = 0
    while queue:
        _, g, cell = heapq.heappop(queue)
        if done[cell]:
            continue                             # a stale entry: this cell was reached cheaper
        if cell == target:
            return _walk_back(came_from, cell, cols), expanded
        done[cell] = 1
        expanded += 1
        r, c = divmod(cell, cols)
        for dr, dc, step in MOVES:
            nr, nc = r + dr, c + dc
            if not (0 <= nr < rows and 0 <= nc < cols):
                continue
            n = nr * cols + nc
            if not is_free[n] or done[n]:
                continue
            if dr and dc and not (is_free[r * cols + nc] and is_free[nr * cols + c]):
                continue                         # a diagonal step must not cut an occupied corner
            new = g + step
            if new < cost.get(n, math.inf):
                cost[n] = new
                came_from[n] = cell
                heapq.heappush(queue, (new + octile((nr, nc), goal), new, n))
    raise NoPath(f"the goal is walled off from the start ({expanded} cells reachable)")


def _walk_back(came_from: dict[int, int], cell: int, cols: int) -> list[tuple[int, int]]:
    path = [divmod(cell, cols)]
    while cell in came_from:
        cell = came_from[cell]
        path.append(divmod(cell, cols))
    return path[::-1]


def line_free(free: np.ndarray, a: tuple[int, int], b: tuple[int, int]) -> bool:
    """Does the straight line between the centres of cells a and b cross free cells only?
    (Sampled every quarter cell: a line cannot slip between two samples through a cell.)"""
    n = max(1, math.ceil(4 * math.hypot(b[0] - a[0], b[1] - a[1])))
    t = np.linspace(0.0, 1.0, n + 1)
    rows = np.rint(a[0] + t * (b[0] - a[0])).astype(int)
    cols = np.rint(a[1] + t * (b[1] - a[1])).astype(int)
    return bool(free[rows, cols].all())


def shortcut(free: np.ndarray, cells: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """The path through fewer cells: from each kept cell, straight on to the farthest one a free
    line reaches."""
    if len(cells) <= 2:
        return list(cells)
    kept = [cells[0]]
    i = 0
    while i < len(cells) - 1:
        j = i + 1
        while j + 1 < len(cells) and line_free(free, cells[i], cells[j + 1]):
            j += 1
        kept.append(cells[j])
        i = j
    return kept


def plan(grid: Grid, start: tuple[float, float], goal: tuple[float, float]
         ) -> tuple[list[tuple[float, float]], int]:
    """A path (world x, y points, m) from ``start`` to ``goal`` on ``grid`` (inflated already),
    and the cells expanded. The first point is ``start`` itself, the last ``goal``.
    `NoPath` says why there is none."""
    free = grid.cells == FREE
    ends = []
    for name, (x, y) in (("start", start), ("goal", goal)):
        cell = grid.cell(x, y)
        if not grid.contains(*cell):
            raise NoPath(f"the {name} ({x:.3f}, {y:.3f}) is outside the map")
        if not free[cell]:
            raise NoPath(f"the {name} ({x:.3f}, {y:.3f}) is inside an obstacle, or closer to one "
                         f"than the robot's radius ({grid.inflation:.3f} m)")
        ends.append(cell)
    cells, expanded = astar(free, ends[0], ends[1])
    points = [grid.centre(r, c) for r, c in shortcut(free, cells)]
    points[0], points[-1] = start, goal         # exactly where asked: within the same cells
    return points, expanded


def length(points: list[tuple[float, float]]) -> float:
    """Length of a polyline, m."""
    return sum(math.dist(a, b) for a, b in itertools.pairwise(points))
