"""viz draws the occupancy grid the grid service answers on ``map/grid``: one image on the map,
each cell on its own square of the world, drawn again only when the grid changes; and refuses,
with one line naming the key and the field, a grid that cannot be one (sizes that disagree, a
grid too large to draw, not a grid at all), on another robot's key, while it keeps drawing the
first robot's. Real processes (router, grid service, viz) and the .rrd read back. ~30 s."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest
import rerun as rr
from conftest import wait_for

from icefloe.grid import MAX_CELLS, of_robot
from icefloe.runtime import Node
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m
from icefloe.services.viz.logging_rr import RobotLogger, grid_cells
from icefloe.services.viz.readback import read_static


def grid_message(grid: np.ndarray, **fields) -> m.OccupancyGrid:
    """A ``map/grid`` answer with these cells, 5 cm cells from (-1.0, -0.5); ``fields`` override."""
    rows, cols = grid.shape
    values = {"stamp": 1, "world": "test", "resolution": 0.05, "origin_x": -1.0, "origin_y": -0.5,
              "width": cols, "height": rows, "inflation": 0.0, "cells": grid.astype(np.uint8).tobytes(), **fields}
    return m.OccupancyGrid(**values)


def drawn_grid(path, robot: str) -> dict:
    """The static ``map/grid`` rows of a recording (what was drawn, one row per change), each
    column's rows as their one instance."""
    columns = read_static(path).get(f"/robots/{robot}/map/grid", {})
    return {name: [row[0] for row in rows] for name, rows in columns.items()}


def image_of(drawn: dict, row: int) -> np.ndarray:
    fmt = drawn["SegmentationImage:format"][row]
    return np.array(drawn["SegmentationImage:buffer"][row], dtype=np.uint8).reshape(fmt["height"], fmt["width"])


# --------------------------------------------------------------------------- pure


@pytest.mark.parametrize(("fields", "named"), [
    ({"width": 7}, "field `cells` has 12 bytes, not `width` x `height` = 7 x 3 = 21"),
    ({"cells": b"\x00" * 11}, "field `cells` has 11 bytes"),
    ({"width": 0}, "`width` x `height`: 0 x 3 is no grid"),
    ({"width": 100_000, "height": 100_000}, f"more than the {MAX_CELLS} cells"),
    ({"resolution": 0.0}, "field `resolution` must be > 0"),
    ({"cells": bytes([0, 1, 2] * 4)}, "field `cells`: a cell is 0 (free) or 1 (occupied), not 2"),
])
def test_a_grid_that_cannot_be_one_is_refused_naming_the_field(fields: dict, named: str) -> None:
    with pytest.raises(ValueError, match="field") as refused:
        grid_cells(grid_message(np.zeros((3, 4)), **fields))
    assert named in str(refused.value) and "\n" not in str(refused.value)


def test_the_grid_is_drawn_once_per_change_with_its_cells_on_their_squares(tmp_path) -> None:
    out = tmp_path / "grid.rrd"
    rec = rr.RecordingStream("icefloe-test")
    rec.save(out)
    logger = RobotLogger(rec, "r1")
    cells = np.zeros((3, 4), np.uint8)
    cells[0, 1] = 1   # bottom row, second column: x in [-0.95, -0.90), y in [-0.5, -0.45)
    assert logger.grid(grid_message(cells))
    assert not logger.grid(grid_message(cells, stamp=2))  # asked again, the same grid: not drawn again
    assert not logger.grid(grid_message(cells, stamp=3))
    cells[2, 3] = 1
    assert logger.grid(grid_message(cells, stamp=4))     # it changed
    rec.flush()
    rec.disconnect()
    drawn = drawn_grid(out, "r1")
    assert len(drawn["SegmentationImage:buffer"]) == 2
    assert (image_of(drawn, -1) == cells).all()  # row 0 first: under the map's y flip, the bottom row
    (tx, ty, tz), (sx, sy, sz) = drawn["Transform3D:translation"][-1], drawn["Transform3D:scale"][-1]
    # pixel (col, row) spans [col, col + 1) x [row, row + 1): scaled and moved, cell (0, 1)'s square
    assert (tx, ty, tz) == pytest.approx((-1.0, -0.5, 0.0)) and (sx, sy, sz) == pytest.approx((0.05, 0.05, 1.0))
    assert tx + 1 * sx == pytest.approx(-0.95) and ty + 0 * sy == pytest.approx(-0.5)


# --------------------------------------------------------------------------- real processes


async def test_viz_draws_the_grid_service_s_grid_and_refuses_a_bad_one_on_another_robot(make_robot,
                                                                                       tmp_path) -> None:
    robot = make_robot()
    robot.start("grid")
    out = tmp_path / "viz.rrd"
    viz = robot.start_module("icefloe.services.viz", "--save", str(out))
    other = msgspec.structs.replace(robot.config, name=f"{robot.name}b")
    other_key = keys.key(other.name, keys.MAP_GRID)
    answers = iter([
        b"\xc1 not msgpack",                                                        # not a grid at all
        codec.encode(grid_message(np.zeros((3, 4)), width=7)),                      # sizes that disagree
        codec.encode(grid_message(np.zeros((2001, 2001)))),                          # too large to draw
    ])
    current = [next(answers)]
    asked = [0]

    def answer(query) -> None:  # a student's queryable on the other robot's key, raw: any bytes at all
        asked[0] += 1
        query.reply(other_key, current[0])

    async with Node("student", other) as student:
        queryable = student.session.declare_queryable(other_key, answer)
        try:
            await wait_for(lambda: viz.output.count("showing robot") >= 2, timeout=60)
            mine = keys.key(robot.name, keys.MAP_GRID)
            await wait_for(lambda: f"{mine}: drew the occupancy grid of world 'lab'" in viz.output, timeout=60)
            for expected in ("not valid MessagePack", "field `cells` has 12 bytes, not `width` x `height` = 7 x 3",
                             f"fields `width` x `height`: 2001 x 2001 cells (4004001 bytes in `cells`), "
                             f"more than the {MAX_CELLS} cells"):
                await wait_for(lambda e=expected: f"{other_key}: dropped" in viz.output and e in viz.output,
                               timeout=30)
                current[0] = next(answers, current[0])
            # asked twice more for the same too large grid (viz asks again only once it has dealt
            # with an answer): still the one line
            now = asked[0]
            await wait_for(lambda: asked[0] >= now + 2, timeout=30)
            assert viz.output.count("2001 x 2001 cells") == 1, viz.output
            assert viz.alive(), viz.output
        finally:
            queryable.undeclare()
    assert viz.stop() == 0, viz.output

    grid = of_robot(robot.config)
    drawn = drawn_grid(out, robot.name)
    assert len(drawn["SegmentationImage:buffer"]) == 1  # asked every few seconds, drawn once
    assert image_of(drawn, 0).shape == grid.shape and (image_of(drawn, 0) == grid.cells).all()
    assert drawn["Transform3D:translation"][0] == pytest.approx([grid.origin_x, grid.origin_y, 0.0])
    assert drawn["Transform3D:scale"][0] == pytest.approx([grid.resolution, grid.resolution, 1.0])
    assert drawn_grid(out, other.name) == {}  # the other robot's bad grids drew nothing


def test_a_recording_played_in_viz_shows_the_world_s_grid(tmp_path) -> None:
    """An MCAP recording holds no query answers: ``icefloe viz FILE.mcap`` draws the grid of the
    config's world, as it draws its landmarks and obstacles."""
    from icefloe import config as config_mod
    from icefloe.bag import Bag
    from icefloe.bag.writer import BagWriter
    from icefloe.services.viz.options import VizOptions
    from icefloe.services.viz.playback import show

    config = config_mod.load()
    run = tmp_path / "run.mcap"
    writer = BagWriter(run)
    pose = m.Pose(stamp=1_000_000_000, x=0.1, y=0.2, theta=0.0, v=0.0, w=0.0)
    writer.write(keys.key("r1", keys.ODOM_POSE), codec.encode(pose), "application/msgpack", pose.stamp)
    writer.close()
    out = tmp_path / "played.rrd"
    assert show(Bag([run]), config, VizOptions(save=str(out))) == 1
    grid, drawn = of_robot(config), drawn_grid(out, "r1")
    assert (image_of(drawn, 0) == grid.cells).all()
    assert drawn["Transform3D:translation"][0] == pytest.approx([grid.origin_x, grid.origin_y, 0.0])
