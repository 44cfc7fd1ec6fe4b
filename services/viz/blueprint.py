"""The default layout of the viewer: everything in view without a click.

One tab per robot (a single robot gets its layout without tabs)::

    +-------------------+----------------+----------------------+
    |                   |  camera image  |  wheel speeds        |
    |   top-down map    |  + markers     |  battery voltage     |
    |                   +----------------+  battery current     |
    +-------------------+  OLED screen   |  loop latency (ms)   |
    |   log             +----------------+  overruns, link err. |
    |                   |  lap judge     |  lap time, penalties |
    +-------------------+----------------+----------------------+

Plots show the last `PLOT_WINDOW_S` seconds before the time cursor, so a live
view scrolls and scrubbing back shows the moment you picked.
"""

from __future__ import annotations

from collections.abc import Sequence

import rerun.blueprint as rrb

from .logging_rr import TIMELINE

PLOT_WINDOW_S = 30.0


def _recent(seconds: float = PLOT_WINDOW_S) -> rrb.VisibleTimeRange:
    return rrb.VisibleTimeRange(
        TIMELINE,
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=-seconds),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )


def _plot(origin: str, name: str) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(origin=origin, name=name, time_ranges=_recent())


def robot_layout(robot: str) -> rrb.Horizontal:
    """The views of one robot, all rooted at ``/robots/<robot>``."""
    root = f"/robots/{robot}"
    return rrb.Horizontal(
        rrb.Vertical(
            # Rooted above the map, so the map's y flip (logging_rr.MAP_FLIP) applies: x right, y up.
            rrb.Spatial2DView(origin=root, contents="$origin/map/**", name=f"{robot}: map (m)"),
            rrb.TextLogView(origin=f"{root}/log", name="log"),
            row_shares=[3, 1],
        ),
        rrb.Vertical(
            rrb.Spatial2DView(origin=f"{root}/camera", name="camera"),
            rrb.Spatial2DView(origin=f"{root}/oled", name="OLED"),
            rrb.TextDocumentView(origin=f"{root}/judge/lap", name="lap judge"),
            row_shares=[6, 2, 1],
        ),
        rrb.Vertical(
            _plot(f"{root}/wheels", "wheel speed (m/s): target vs measured"),
            _plot(f"{root}/battery/voltage", "battery (V)"),
            _plot(f"{root}/battery/current", "current (A)"),
            _plot(f"{root}/loop/latency_ms", "hwbridge wake-up latency (ms)"),
            _plot(f"{root}/loop/errors", "overruns, link errors"),
            _plot(f"{root}/judge", "lap judge: lap time, penalties (s)"),
        ),
        column_shares=[4, 3, 3],
        name=robot,
    )


def blueprint(robots: Sequence[str]) -> rrb.Blueprint:
    """The default blueprint for these robots (sorted, so the tab order is stable)."""
    layouts = [robot_layout(r) for r in sorted(robots)]
    if not layouts:
        root: rrb.Container = rrb.Tabs(rrb.TextLogView(origin="/", name="waiting for robots"))
    elif len(layouts) == 1:
        root = layouts[0]
    else:
        root = rrb.Tabs(*layouts)
    return rrb.Blueprint(
        root,
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(timeline=TIMELINE, state="collapsed"),  # collapsed still shows play/follow
    )
