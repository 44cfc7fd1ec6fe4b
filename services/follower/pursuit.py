"""Pure pursuit: the reference follower's maths, as a student would write it.

The robot steers at a point a fixed distance (the *lookahead*) ahead along the path. The arc
from the robot through that point has curvature ``k = 2 y / L**2``, where ``y`` is the point's
sideways offset in the robot's frame and ``L`` its distance (R. C. Coulter, *Implementation of
the Pure Pursuit Path Tracking Algorithm*, CMU-RI-TR-92-01). Driving at speed ``v``, the turn
rate is ``w = v k``. Near the end the point is the path's last one, and the speed falls with
the distance left so the robot stops on it, not past it.

Two more rules make it drive a planner's path of a few corners: when the point is far off
the heading (behind, at the start) the robot turns on the spot first; and progress along the
path only moves forwards (the nearest point is searched from the last one on), so a path that
passes near itself is not cut short.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

Point = tuple[float, float]


@dataclass(frozen=True)
class Params:
    speed: float = 0.15
    """Forward speed, m/s."""
    lookahead: float = 0.15
    """m."""
    max_turn_rate: float = 1.5
    """rad/s."""
    turn_in_place: float = 0.5
    """Turn on the spot when the target is more than this off the heading, rad."""
    goal_tolerance: float = 0.03
    """m."""
    min_speed: float = 0.04
    """Slowest forward speed while not yet there, m/s (slower, the motors barely turn)."""
    slow_down: float = 1.0
    """Near the end, the speed is at most this times the distance left, (m/s) per m."""


@dataclass(frozen=True)
class Step:
    v: float
    """Forward speed to command, m/s."""
    w: float
    """Turn rate to command, rad/s."""
    progress: tuple[int, float]
    """(segment, fraction along it) of the point of the path nearest the robot."""
    cross_track: float
    """Distance from the robot to the path, m."""
    remaining: float
    """Distance left along the path from the nearest point to its end, m."""
    arrived: bool


def project(a: Point, b: Point, p: Point) -> tuple[float, float]:
    """(fraction t in [0, 1] along segment a-b of the point nearest p, its distance to p)."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    span = dx * dx + dy * dy
    t = 0.0 if span == 0 else max(0.0, min(1.0, ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / span))
    return t, math.hypot(a[0] + t * dx - p[0], a[1] + t * dy - p[1])


def nearest(path: list[Point], p: Point, since: tuple[int, float], window: float) -> tuple[int, float, float]:
    """The point of ``path`` nearest ``p``, searched from ``since`` on for ``window`` m of path:
    (segment, fraction, distance)."""
    best = (since[0], since[1], math.inf)
    travelled = 0.0                          # path searched, from `since` on
    for i in range(since[0], len(path) - 1):
        t, d = project(path[i], path[i + 1], p)
        span = math.dist(path[i], path[i + 1])
        if i == since[0]:
            t = max(t, since[1])             # never backwards
            d = math.dist(_along(path, i, t), p)
            span *= 1.0 - since[1]
        if d < best[2]:
            best = (i, t, d)
        travelled += span
        if travelled > window:
            break
    return best


def _along(path: list[Point], i: int, t: float) -> Point:
    a, b = path[i], path[i + 1]
    return (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]))


def ahead(path: list[Point], i: int, t: float, distance: float) -> Point:
    """The point ``distance`` m further along the path from segment i, fraction t (or its end)."""
    left = distance
    while i < len(path) - 1:
        here = _along(path, i, t)
        rest = math.dist(here, path[i + 1])
        if rest >= left:
            return _along(path, i, t + (1 - t) * left / rest) if rest else here
        left -= rest
        i, t = i + 1, 0.0
    return path[-1]


def remaining_length(path: list[Point], i: int, t: float) -> float:
    if i >= len(path) - 1:
        return 0.0
    here = _along(path, i, t)
    return math.dist(here, path[i + 1]) + sum(math.dist(path[j], path[j + 1]) for j in range(i + 1, len(path) - 1))


def step(path: list[Point], pose: tuple[float, float, float], since: tuple[int, float], p: Params) -> Step:
    """One control step: where the robot (x, y, theta) is on the path, and the twist to drive."""
    x, y, theta = pose
    if len(path) == 1:                        # one point: from where the robot is, straight to it
        path = [(x, y), path[0]]
        since = (0, 0.0)
    i, t, cross = nearest(path, (x, y), since, window=4 * p.lookahead + 0.5)
    left = remaining_length(path, i, t)
    to_end = math.dist((x, y), path[-1])
    if to_end <= p.goal_tolerance or (left <= p.goal_tolerance and _passed(path, (x, y, theta))):
        return Step(0.0, 0.0, (i, t), cross, left, True)
    tx, ty = ahead(path, i, t, p.lookahead)
    if math.dist((tx, ty), (x, y)) < 1e-6:
        tx, ty = path[-1]
    # the target in the robot's frame
    dx, dy = tx - x, ty - y
    fx, fy = dx * math.cos(theta) + dy * math.sin(theta), -dx * math.sin(theta) + dy * math.cos(theta)
    alpha = math.atan2(fy, fx)
    if abs(alpha) > p.turn_in_place:        # turn towards it (in proportion: no overshoot)
        return Step(0.0, max(-p.max_turn_rate, min(p.max_turn_rate, 2.0 * alpha)), (i, t), cross, left, False)
    v = max(p.min_speed, min(p.speed, p.slow_down * to_end))
    curvature = 2.0 * fy / (fx * fx + fy * fy)
    w = v * curvature
    if abs(w) > p.max_turn_rate:           # too sharp at this speed: slow down, keep the arc
        v, w = p.max_turn_rate / abs(curvature), math.copysign(p.max_turn_rate, w)
    return Step(v, w, (i, t), cross, left, False)


def _passed(path: list[Point], pose: tuple[float, float, float]) -> bool:
    """Is the robot level with or past the path's end (along the last segment's direction)?"""
    (ax, ay), (bx, by) = path[-2], path[-1]
    if (ax, ay) == (bx, by):
        return True
    return (pose[0] - bx) * (bx - ax) + (pose[1] - by) * (by - ay) >= 0
