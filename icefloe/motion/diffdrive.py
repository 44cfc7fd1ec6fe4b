"""The differential base: a body twist as wheel rim speeds, and the wheels' speed limit.

Units: m/s for speeds, rad/s for turn rates, m for the track (the distance between the wheels'
contact points).
"""

from __future__ import annotations

import math


def twist_to_wheels(v: float, w: float, track: float) -> tuple[float, float]:
    """Body twist (v m/s forward, w rad/s CCW) -> (left, right) rim speeds, m/s."""
    half = w * track / 2.0
    return v - half, v + half


def limit_wheels(left: float, right: float, max_speed: float) -> tuple[float, float, bool]:
    """Scale both wheel speeds down together so neither exceeds ``max_speed`` (m/s).

    Scaling both keeps the curvature the user asked for (clamping each wheel on
    its own would turn an arc into a different arc). Returns (left, right, clamped).
    """
    biggest = max(abs(left), abs(right))
    if biggest <= max_speed:
        return left, right, False
    if math.isinf(biggest):  # a huge twist overflowed: inf * 0 would be NaN; the limit of the scaling
        return _towards_inf(left, max_speed), _towards_inf(right, max_speed), True
    scale = max_speed / biggest
    return left * scale, right * scale, True


def _towards_inf(speed: float, max_speed: float) -> float:
    return math.copysign(max_speed, speed) if math.isinf(speed) else 0.0
