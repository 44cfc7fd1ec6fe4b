"""The `grid` verb: a world's occupancy grid as a file (PNG, NumPy), the map the planner uses."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import IcefloeError


def grid(args: argparse.Namespace) -> int:
    from ..grid import from_world
    from ..worldmap import load_world

    for out in args.out or []:
        if Path(out).suffix.lower() not in (".png", ".npy", ".npz"):
            raise IcefloeError(f"{out}: write .png, .npy or .npz")
    world = load_world(args.world)
    try:
        made = from_world(world, args.resolution).inflate(args.inflate)
    except ValueError as exc:
        raise IcefloeError(str(exc)) from None
    rows, cols = made.shape
    occupied = int(made.cells.sum())
    print(f"grid of world {made.world}: {cols} x {rows} cells of {made.resolution:g} m, origin "
          f"({made.origin_x:+.3f}, {made.origin_y:+.3f}) m, obstacles grown by {made.inflation:g} m, "
          f"{occupied} cells ({100 * occupied / made.cells.size:.1f} %) occupied")
    for out in args.out or []:
        try:
            path = made.save(out)
        except (OSError, ValueError) as exc:
            raise IcefloeError(str(exc)) from None
        print(f"wrote {path}")
    return 0


def _metres(text: str) -> float:
    value = float(text)
    if not 0 <= value <= 10:  # (NaN fails too)
        raise argparse.ArgumentTypeError(f"{text}: give a number of metres from 0 to 10")
    return value


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("grid", help="a world's occupancy grid as a file (PNG, NumPy): the planner's map",
                         description="Make the occupancy grid of a world's obstacles (icefloe/grid.py), as the "
                                     "grid service serves it on map/grid, and write it: .png (white free, black "
                                     "occupied, north up), .npy (the cells, row 0 at the bottom: occgrid[y, x]) "
                                     "or .npz (the cells with their resolution and origin).")
    p.add_argument("world", metavar="WORLD", help="a world name (lab) or a world .toml file")
    p.add_argument("--resolution", type=_metres, default=0.02, help="side of a cell, m (default 0.02)")
    p.add_argument("--inflate", type=_metres, default=0.0,
                   help="grow the obstacles by this much, m: the robot's radius gives the free space of its "
                        "centre (default 0)")
    p.add_argument("--out", "-o", action="append", metavar="FILE",
                   help="write the grid to FILE (.png, .npy or .npz); may be given more than once")
    p.set_defaults(run=grid)
