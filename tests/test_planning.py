"""Obstacles, the occupancy grid, A* and pure pursuit as pure logic: known worlds, grids and paths.

Also the simulator's collisions (`World` with obstacles) and the messages' hostile input (a
path with NaN, too many points). The services as processes: tests/test_planning_sim.py.
"""

from __future__ import annotations

import itertools
import math
import re
from pathlib import Path

import msgspec
import numpy as np
import pytest

from icefloe.config import Geometry
from icefloe.errors import BadPayload, ConfigError
from icefloe.grid import FREE, OCCUPIED, Grid, from_world, load
from icefloe.schemas import codec
from icefloe.schemas import messages as m
from icefloe.services.follower.pursuit import Params, step
from icefloe.services.planner.astar import NoPath, astar, length, line_free, octile, plan, shortcut
from icefloe.sim.world import World
from icefloe.worldmap import load_world, parse_world

DEFAULTS = Params()
WALL = {"kind": "wall", "x0": 0.0, "y0": -1.0, "x1": 0.0, "y1": 1.0, "thickness": 0.1}


def world(*obstacles: dict) -> object:
    return parse_world({"obstacle": list(obstacles)}, "test.toml")


# ---------------------------------------------------------------------- worlds


def test_the_lab_has_walls_and_boxes_and_a_clear_start() -> None:
    lab = load_world("lab")
    assert [o.__class__.__name__ for o in lab.obstacles] == ["Wall"] * 5 + ["Box"] * 2
    assert lab.clearance(0.0, 0.0) > 0.5                        # the start pose is clear
    assert lab.clearance(2.0, 0.0) == 0.0 and lab.clearance(-0.9, -0.9) == 0.0


@pytest.mark.parametrize(
    ("obstacle", "message"),
    [
        ({**WALL, "x1": 0.0, "y1": -1.0}, "obstacle[0]: the wall's two ends (x0, y0) and (x1, y1) are the same point"),
        ({**WALL, "thickness": 0.0}, "obstacle[0]: `thickness` must be > 0"),
        ({**WALL, "x0": math.nan}, "obstacle[0]: `x0` must be a finite number"),
        ({**WALL, "colour": "red"}, "[obstacle[0]]: Object contains unknown field `colour`"),
        ({"kind": "box", "x": 0.0, "y": 0.0, "length": 0.0, "width": 1.0}, "obstacle[0]: `length` and `width`"),
        ({"kind": "box", "x": 0.0, "y": 0.0, "length": 1.0}, "obstacle[0]: Object missing required field `width`"),
        ({"kind": "tree", "x": 0.0}, "obstacle[0].kind: Invalid value 'tree'"),
        ({"x": 0.0}, "obstacle[0]: Object missing required field `kind`"),
    ],
)
def test_bad_obstacles_name_the_obstacle_and_key(tmp_path: Path, obstacle: dict, message: str) -> None:
    path = tmp_path / "w.toml"
    path.write_text("")
    with pytest.raises(ConfigError) as err:
        parse_world({"obstacle": [obstacle]}, str(path))
    assert str(err.value).startswith(f"{path}: ") and message in str(err.value), str(err.value)


# ---------------------------------------------------------------------- the grid


def test_a_box_fills_the_cells_it_touches_and_no_others() -> None:
    grid = from_world(world({"kind": "box", "x": 0.5, "y": 0.5, "length": 0.3, "width": 0.3}), 0.1)
    # the box covers x, y in [0.35, 0.65]: parts of four cells each way
    occupied = {grid.centre(r, c) for r, c in zip(*np.nonzero(grid.cells), strict=True)}
    xs = sorted({round(x, 3) for x, _ in occupied})
    assert xs == [0.35, 0.45, 0.55, 0.65] and {round(y, 3) for _, y in occupied} == set(xs)
    assert grid.origin_x <= 0.3 - 0.1 + 1e-9 and grid.cells[0].sum() == 0   # one free cell around it
    assert grid.cell(0.5, 0.5) in set(zip(*np.nonzero(grid.cells), strict=True))


def test_inflating_grows_the_obstacles_by_the_radius() -> None:
    far = {"kind": "box", "x": 1.0, "y": 0.0, "length": 0.1, "width": 0.1}   # (the grid reaches it)
    grid = from_world(world({**WALL, "x0": -1.0, "x1": -1.0}, WALL, far), 0.02)
    inflated = grid.inflate(0.1)
    row = grid.cell(0.0, 0.0)[0]
    xs = [x for c in np.nonzero(inflated.cells[row])[0] if abs(x := grid.centre(row, c)[0]) < 0.5]
    assert inflated.inflation == 0.1 and inflated.cells.sum() > grid.cells.sum()
    assert min(xs) == pytest.approx(-0.05 - 0.01 - 0.1, abs=0.021) and max(xs) == pytest.approx(0.16, abs=0.021)
    assert grid.inflate(0.0) is grid


def test_a_world_grid_is_the_same_every_time_and_on_a_resolution_grid() -> None:
    a, b = (from_world(load_world("lab"), 0.02) for _ in range(2))
    assert np.array_equal(a.cells, b.cells) and a.shape == (208, 208)
    assert a.origin_x / 0.02 == pytest.approx(round(a.origin_x / 0.02))
    with pytest.raises(ValueError, match="more than 4000000 cells"):
        from_world(load_world("lab"), 0.001)
    with pytest.raises(ValueError, match="resolution must be"):
        from_world(load_world("lab"), float("nan"))


@pytest.mark.parametrize("suffix", [".npz", ".npy", ".png"])
def test_grid_files_read_back_the_same_cells(tmp_path: Path, suffix: str) -> None:
    grid = from_world(load_world("lab"), 0.05).inflate(0.1)
    path = grid.save(tmp_path / f"lab{suffix}")
    back = load(path) if suffix == ".npz" else load(path, 0.05, (grid.origin_x, grid.origin_y))
    assert np.array_equal(back.cells, grid.cells) and back.resolution == 0.05
    assert (back.origin_x, back.origin_y) == (grid.origin_x, grid.origin_y)
    if suffix == ".npz":
        assert (back.inflation, back.world) == (0.1, "lab")
    if suffix == ".png":  # north up: the picture's top line is the grid's last row
        import cv2

        picture = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        assert np.array_equal(picture[0] == 0, grid.cells[-1] == OCCUPIED)


def test_bad_grid_files_name_the_file(tmp_path: Path) -> None:
    (tmp_path / "a.png").write_bytes(b"not a picture")
    np.save(tmp_path / "b.npy", np.full((3, 3), 7))
    np.save(tmp_path / "c.npy", np.zeros(5))
    for name, resolution, message in [("a.png", 0.1, "not a picture"), ("b.npy", 0.1, "must be 0 (free) or 1"),
                                      ("c.npy", 0.1, "2-D array"), ("b.npy", 0.0, "must be 0 (free)"),
                                      ("d.npz", 0.1, "No such file"), ("e.txt", 0.1, "read .png, .npy or .npz")]:
        with pytest.raises(ValueError, match=re.escape(message)) as err:
            load(tmp_path / name, resolution)
        assert str(err.value).startswith(str(tmp_path / name))
    np.save(tmp_path / "f.npy", np.zeros((3, 3)))
    with pytest.raises(ValueError, match="resolution must be"):
        load(tmp_path / "f.npy")


# ---------------------------------------------------------------------- A*


def grid_of(rows: list[str], resolution: float = 1.0) -> Grid:
    """A grid drawn as text, top line north: '#' occupied, '.' free."""
    cells = np.array([[OCCUPIED if ch == "#" else FREE for ch in line] for line in rows[::-1]], np.uint8)
    return Grid(cells, resolution, 0.0, 0.0)


def test_astar_on_an_empty_grid_goes_straight_and_diagonal() -> None:
    free = np.ones((10, 10), bool)
    cells, _ = astar(free, (0, 0), (0, 9))
    assert cells == [(0, c) for c in range(10)]
    cells, _ = astar(free, (0, 0), (9, 9))
    assert cells == [(i, i) for i in range(10)]
    cells, _ = astar(free, (0, 0), (3, 9))
    assert len(cells) - 1 == 9 and octile((0, 0), (3, 9)) == pytest.approx(6 + 3 * math.sqrt(2))


def test_astar_goes_round_a_wall_by_the_shortest_way_and_cuts_no_corner() -> None:
    g = grid_of([".......",
                 "...#...",
                 "...#...",
                 "...#...",
                 "......."])
    free = g.cells == FREE
    cells, _ = astar(free, (2, 0), (2, 6))
    cost = sum(math.dist(a, b) for a, b in itertools.pairwise(cells))
    assert cost == pytest.approx(2 + 4 * math.sqrt(2))   # diagonally to the wall's end, 2 straight past it, down
    assert all(free[c] for c in cells)
    for (r0, c0), (r1, c1) in itertools.pairwise(cells):
        assert free[r0, c1] and free[r1, c0]                       # never a diagonal past a corner


def test_no_path_says_why() -> None:
    g = grid_of(["..#..",
                 "..#..",
                 "..#.."])
    with pytest.raises(NoPath, match="walled off"):
        plan(g, (0.5, 1.5), (4.5, 1.5))
    with pytest.raises(NoPath, match=r"the goal \(2.500, 1.500\) is inside an obstacle"):
        plan(g, (0.5, 1.5), (2.5, 1.5))
    with pytest.raises(NoPath, match=r"the start \(-3.000, 1.000\) is outside the map"):
        plan(g, (-3.0, 1.0), (0.5, 0.5))
    diagonal_gap = grid_of(["...#",
                            "..#.",
                            "...."[:0] + ".#..",
                            "#..."])
    with pytest.raises(NoPath):   # the only way through is between two corners
        plan(diagonal_gap, (3.5, 3.5), (0.5, 0.5))


def test_shortcut_keeps_a_path_in_free_cells() -> None:
    g = grid_of([".......",
                 "...#...",
                 "...#...",
                 "......."])
    free = g.cells == FREE
    cells, _ = astar(free, (1, 0), (1, 6))
    short = shortcut(free, cells)
    assert short[0] == cells[0] and short[-1] == cells[-1] and len(short) < len(cells)
    assert all(line_free(free, a, b) for a, b in itertools.pairwise(short))
    assert not line_free(free, (1, 0), (1, 6))


def test_the_lab_plan_goes_round_the_partition_on_free_cells() -> None:
    grid = from_world(load_world("lab"), 0.02).inflate(0.15)
    points, expanded = plan(grid, (-1.5, 1.3), (1.5, -1.6))
    assert points[0] == (-1.5, 1.3) and points[-1] == (1.5, -1.6) and expanded > 0
    straight = math.dist((-1.5, 1.3), (1.5, -1.6))
    assert straight < length(points) < 1.3 * straight
    lab = load_world("lab")
    for a, b in itertools.pairwise(points):   # every point of every leg clear of every obstacle
        for t in np.linspace(0, 1, 50):
            assert lab.clearance(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])) >= 0.15 - 0.03


# ---------------------------------------------------------------------- pure pursuit


def drive(path: list[tuple[float, float]], pose=(0.0, 0.0, 0.0), params: Params = DEFAULTS, dt: float = 0.05,
          steps: int = 4000) -> tuple[tuple[float, float, float], list[float], bool]:
    """A unicycle driven by `step` (exactly as commanded): its end pose, cross-track errors, arrived."""
    x, y, th = pose
    since, errors = (0, 0.0), []
    for _ in range(steps):
        s = step(path, (x, y, th), since, params)
        since = s.progress
        errors.append(s.cross_track)
        if s.arrived:
            return (x, y, th), errors, True
        th += s.w * dt
        x, y = x + s.v * math.cos(th) * dt, y + s.v * math.sin(th) * dt
    return (x, y, th), errors, False


def test_pursuit_drives_a_straight_line_on_it_and_stops_at_its_end() -> None:
    end, errors, arrived = drive([(0.0, 0.0), (1.0, 0.0)])
    assert arrived and math.dist(end[:2], (1.0, 0.0)) <= Params().goal_tolerance + 1e-9
    assert max(errors) < 1e-9


def test_pursuit_turns_on_the_spot_towards_a_path_behind_it_and_joins_it() -> None:
    end, errors, arrived = drive([(0.0, 0.0), (-1.0, 0.0)])
    assert arrived and math.dist(end[:2], (-1.0, 0.0)) < 0.04 and max(errors) < 0.03
    s = step([(0.0, 0.0), (-1.0, 0.0)], (0.0, 0.0, 0.0), (0, 0.0), Params())
    assert s.v == 0 and abs(s.w) == Params().max_turn_rate


def test_pursuit_follows_a_square_and_cuts_its_corners_by_little() -> None:
    end, errors, arrived = drive([(0, 0), (1, 0), (1, 1), (0, 1), (0, 0)])
    assert arrived and math.dist(end[:2], (0, 0)) < 0.04
    assert max(errors) < 0.05 and float(np.median(errors)) < 0.005


def test_pursuit_to_one_point_and_from_off_the_path() -> None:
    end, _, arrived = drive([(0.5, 0.5)])
    assert arrived and math.dist(end[:2], (0.5, 0.5)) < 0.04
    end, errors, arrived = drive([(0.0, 0.3), (2.0, 0.3)])
    assert arrived and math.dist(end[:2], (2.0, 0.3)) < 0.04 and errors[-1] < 0.01


def test_progress_never_goes_back_along_a_path_that_passes_near_itself() -> None:
    # out and back along almost the same line: the robot must not skip to the way back
    path = [(0.0, 0.0), (1.0, 0.0), (1.0, 0.05), (0.0, 0.05)]
    end, _, arrived = drive(path)
    assert arrived and math.dist(end[:2], (0.0, 0.05)) < 0.04


# ---------------------------------------------------------------------- hostile messages


def test_a_path_with_nan_or_too_many_points_is_refused_naming_the_point() -> None:
    nan = msgspec.msgpack.encode({"points": [{"x": 0.0, "y": 0.0}, {"x": float("nan"), "y": 1.0}]})
    with pytest.raises(BadPayload, match=r"point 1 is not finite"):
        codec.decode(nan, "application/msgpack", m.NavPath, "icefloe/sim/nav/path")
    many = msgspec.msgpack.encode({"points": [{"x": 0.0, "y": 0.0}] * (m.MAX_PATH_POINTS + 1)})
    with pytest.raises(BadPayload, match="more than"):
        codec.decode(many, "application/msgpack", m.NavPath, "icefloe/sim/nav/path")
    with pytest.raises(BadPayload):
        codec.decode(b'{"points": [{"x": 0, "y": 0, "z": 0}]}', "application/json", m.NavPath, "icefloe/sim/nav/path")
    with pytest.raises(BadPayload):
        codec.decode(b'{"inflation": 5}', "application/json", m.GridRequest, "icefloe/sim/map/grid")


# ---------------------------------------------------------------------- collisions


def test_the_simulated_robot_stops_at_a_wall_and_backs_away_from_it() -> None:
    w = World(Geometry(), seed=1, obstacles=world(WALL).obstacles)
    w.set_pose(-0.5, 0.0, 0.0)
    w.set_duty(0.5, 0.5)
    for _ in range(6000):
        w.step(0.001)
    x, y, _ = w.pose
    assert w.collided and w.collisions == 1
    assert -0.05 - 0.1 - 0.002 < x <= -0.05 - 0.1 and y == pytest.approx(0.0)   # against the face, not in it
    counts = w.counts()
    for _ in range(500):
        w.step(0.001)
    assert w.counts() == counts and w.wheel_speeds == (0.0, 0.0)               # the wheels stand still
    w.set_duty(-0.5, -0.5)
    for _ in range(1000):
        w.step(0.001)
    assert not w.collided and w.pose[0] < x - 0.1 and w.collisions == 1
