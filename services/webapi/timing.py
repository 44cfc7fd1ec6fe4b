"""How long hwbridge holds a timed motion so that it covers V·T (docs/webapi.md, timed motion).

Pure functions, no I/O. The old server held a speed V for T seconds (ramped: A up, T - A held,
A down), which covers V·T on a robot whose wheels follow at once. hwbridge limits how fast a
wheel's speed changes (``hwbridge.max_accel``), the firmware's integral controller starts the
wheels late and the motors run on after the stop: the web API holds the speed for a time T' that
makes up for each (`timed_duration`).
"""

from __future__ import annotations

import bisect

LEAD_TIMES = (0.5, 0.75, 1.0, 2.0)
"""Motion times T (s) of the blocks of `LEAD_MS` (beyond 2 s the lead no longer changes)."""
LEAD_DEMANDS = (15, 20, 30, 40, 50, 65, 80, 94)
"""Speeds (firmware demand units) of the rows of `LEAD_MS`. Below 15 the wheels barely turn against
the firmware's dead band and the figure at 10 swings from -100 to +800 ms: slower speeds take 15's."""
LEAD_ACCELS = (0.0, 0.05, 0.1, 0.2, 0.3, 0.5, 1.0)
"""Ramp times A (s) of the columns of `LEAD_MS`."""
LEAD_MS: tuple[tuple[tuple[float, ...], ...], ...] = (  # bench/timed_motion_model.py --leads
    (  # T = 0.5 s; rows: LEAD_DEMANDS, columns: LEAD_ACCELS
        (28.7, 32.0, 45.9, 23.8, -29.6, -35.9, -50.5),  # 15
        (24.2, 27.5, 43.6, 38.2, 4.7, -38.2, -42.0),  # 20
        (19.6, 13.6, 42.9, 47.8, 28.7, -3.4, -26.6),  # 30
        (20.7, 12.4, 38.6, 55.7, 31.8, 10.9, -16.1),  # 40
        (18.6, 8.6, 31.1, 55.8, 35.6, 14.8, -12.9),  # 50
        (18.8, 6.1, 21.8, 54.8, 38.8, 18.9, -2.0),  # 65
        (5.0, -8.2, 7.4, 41.5, 38.7, 18.5, 0.7),  # 80
        (-26.9, -41.8, -28.3, 0.0, 14.1, 9.3, 2.9),  # 94
    ),
    (  # T = 0.75 s; rows: LEAD_DEMANDS, columns: LEAD_ACCELS
        (6.4, 41.4, 198.5, -5.6, -29.6, -35.9, -50.5),  # 15
        (7.2, 8.3, 28.1, 23.4, 4.7, -38.2, -42.0),  # 20
        (3.2, -1.2, 27.2, 41.9, 28.7, -3.4, -26.6),  # 30
        (5.7, -4.5, 23.2, 42.0, 31.8, 10.9, -16.1),  # 40
        (3.6, -7.0, 16.3, 42.6, 35.6, 14.8, -12.9),  # 50
        (4.6, -7.5, 8.4, 43.0, 38.8, 18.9, -2.0),  # 65
        (-1.3, -15.4, -2.5, 32.0, 38.7, 18.5, 0.7),  # 80
        (-26.6, -41.9, -28.9, -0.5, 14.1, 9.3, 2.9),  # 94
    ),
    (  # T = 1 s; rows: LEAD_DEMANDS, columns: LEAD_ACCELS
        (12.2, 10.9, 27.2, 15.6, -21.6, -35.9, -50.5),  # 15
        (8.9, 12.6, 30.0, 29.4, 12.0, -38.2, -42.0),  # 20
        (6.9, 0.8, 29.9, 40.6, 29.1, -3.4, -26.6),  # 30
        (5.5, -2.4, 26.1, 43.9, 34.6, 10.9, -16.1),  # 40
        (4.7, -6.6, 16.9, 44.0, 41.0, 14.8, -12.9),  # 50
        (4.7, -8.2, 8.7, 44.0, 40.9, 18.9, -2.0),  # 65
        (-1.1, -15.3, -2.4, 33.2, 40.1, 18.5, 0.7),  # 80
        (-27.0, -41.8, -31.9, -2.0, 15.9, 9.3, 2.9),  # 94
    ),
    (  # T = 2 s; rows: LEAD_DEMANDS, columns: LEAD_ACCELS
        (8.2, 12.4, 20.9, 10.4, -18.7, -35.9, -50.5),  # 15
        (8.1, 10.2, 28.1, 25.7, 12.8, -38.2, -42.0),  # 20
        (6.1, -0.0, 28.0, 41.9, 28.1, -3.4, -26.6),  # 30
        (5.2, -2.1, 24.8, 43.7, 35.2, 10.9, -16.1),  # 40
        (4.7, -6.0, 17.5, 44.5, 39.1, 14.8, -12.9),  # 50
        (7.0, -7.7, 8.4, 44.1, 40.4, 18.9, -2.0),  # 65
        (-0.8, -15.5, -2.3, 33.3, 39.5, 18.5, 0.7),  # 80
        (-26.7, -41.8, -31.3, -1.6, 15.8, 9.3, 2.9),  # 94
    ),
)
"""The lead, ms: how much shorter than T' = T + (the slew's deficit)/V a motion is held so that it
covers V·T (what the wheels run on after the stop less what the firmware's integral controller
starts them late), by T, speed and ramp. Measured on the firmware model (its integral controller,
the PWM map, the report's motor) in simulated time by ``bench/timed_motion_model.py --leads``,
the mean over the firmware's 20 ms control phases. A ramp too long for a T (T <= 2A) has the
figure of the shortest T it fits. It is the motor's: docs/webapi.md says what another motor does."""


def _place(grid: tuple[float, ...], x: float) -> tuple[int, float]:
    """Index of the grid cell holding ``x`` (clamped to the grid) and where in it, 0..1."""
    x = min(max(x, grid[0]), grid[-1])
    i = min(max(bisect.bisect_right(grid, x) - 1, 0), len(grid) - 2)
    return i, (x - grid[i]) / (grid[i + 1] - grid[i])


def lead(demand: float, accel: float, duration: float) -> float:
    """`LEAD_MS` at ``demand`` (units, its size), ramp ``accel`` (s) and time ``duration`` (s),
    interpolated; s."""
    k, v = _place(LEAD_TIMES, duration)
    i, u = _place(LEAD_DEMANDS, abs(demand))
    j, w = _place(LEAD_ACCELS, accel)
    ms = 0.0
    for dk, fk in ((0, 1 - v), (1, v)):
        for di, fi in ((0, 1 - u), (1, u)):
            for dj, fj in ((0, 1 - w), (1, w)):
                ms += fk * fi * fj * LEAD_MS[k + dk][i + di][j + dj]
    return ms / 1000


def timed_duration(left: float, right: float, duration: float, accel: float, *, unit: float,
                   max_speed: float, max_accel: float) -> float:
    """T' (s): how long hwbridge holds demands ``left``, ``right`` (firmware units; ``unit`` m/s
    each) so that a motion of ``duration`` s ramped over ``accel`` s covers V·T.

    hwbridge changes a wheel's speed at most ``max_accel`` = a (2 m/s²); the old server's steps
    were instant. A speed V set at once (no ``accel=``) thus takes V/a to reach and covers V²/2a
    less: 4 % of V·T at 40 units for 1 s, 12 % at 90. A ramp of A seconds steeper than a (V/A > a)
    is followed late on the way up and cut by the stop at its end on the way down: (V - aA)²/2a
    less in all (V²/2a for A = 0; nothing for a ramp gentler than a). Holding the speed that much
    longer gives it back. V is the faster wheel's speed as hwbridge limits it (``max_speed``).
    What the wheels then run on beyond V·T (`lead`) comes off.
    """
    speed = min(max(abs(left), abs(right)) * unit, max_speed)
    if speed == 0:
        return duration
    behind = max(0.0, speed - max_accel * accel) ** 2 / (2 * max_accel)  # m
    held = duration + behind / speed - lead(speed / unit, accel, duration)
    # hwbridge's profile needs T' > 2A (a ramp up and a ramp down); and never less than half of T.
    return max(duration / 2, 2 * accel + 0.001 if accel else 0.0, held)
