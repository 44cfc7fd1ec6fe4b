"""Tracks (icefloe/track.py): the road's shape, the route a lap drives, and layout files refused
with one line naming the file and the field."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from icefloe.errors import ConfigError
from icefloe.track import Track, TrackError, load_track, parse_track
from icefloe.worldmap import load_world

LOOP = {
    "tile_size": 0.6, "road_width": 0.3, "start": [0.0, 0.0, 0.0],
    "tile": [{"kind": "curve", "col": 1, "row": 0, "rotation": 90},
             {"kind": "curve", "col": 1, "row": 1, "rotation": 180},
             {"kind": "curve", "col": 0, "row": 1, "rotation": 270},
             {"kind": "curve", "col": 0, "row": 0, "rotation": 0}],
}
"""Four curves: a circle of radius 0.3 m about (0.3, 0.3); `loop` starts it at its bottom, where
curve (0, 0) meets curve (1, 0): (0.3, 0.0)."""


def loop(**changes: object) -> Track:
    return parse_track({**LOOP, "start": [0.3, 0.0, 0.0], **changes}, "t.toml")


def test_shipped_track_is_a_closed_loop_of_the_length_its_tiles_make() -> None:
    track = load_world("track").track
    assert track is not None and track.name == "loop"
    line = track.centerline()
    assert np.allclose(line[0], line[-1]) and np.allclose(line[0], track.start[:2])
    steps = np.hypot(*np.diff(line, axis=0).T)
    assert steps.max() <= 0.0101  # continuous: no jump between tiles
    # 8 straight-through tiles and 2 sharp corners of 0.6 m, 2 quarter circles of radius 0.3 m
    assert track.lap_length() == pytest.approx(10 * 0.6 + 2 * math.pi * 0.3 / 2, abs=1e-3)
    assert 6 <= track.lap_length() <= 10
    assert all(track.on_road(x, y) for x, y in line)
    # in driving order: it leaves the start along the start's yaw (+x) and turns left (counter-clockwise)
    assert line[5, 0] > line[0, 0] and abs(line[5, 1] - line[0, 1]) < 1e-9
    area = 0.5 * np.sum(line[:-1, 0] * line[1:, 1] - line[1:, 0] * line[:-1, 1])
    assert area > 0
    sign = track.signs[0]
    assert track.on_road(sign.stop_x, sign.stop_y) and not track.on_road(sign.x, sign.y)


def test_on_road_follows_each_kind_of_tile() -> None:
    track = load_world("track").track
    assert track is not None
    assert track.on_road(-0.6, -0.6) and track.on_road(-0.6, -0.6 + 0.149)
    assert not track.on_road(-0.6, -0.6 + 0.151) and not track.on_road(-0.6, -0.6 - 0.151)
    assert not track.on_road(5.0, 5.0)  # no tile
    # the T at (0, -0.6): its stem runs north to the tile's edge, not south
    assert track.on_road(0.0, -0.35) and not track.on_road(0.0, -0.85)
    # the sharp corner at (1.2, -0.6) (W and N): the inside of the bend is road, the outside not
    assert track.on_road(1.2, -0.6) and track.on_road(1.2 + 0.14, -0.6 + 0.14)
    assert not track.on_road(1.2 + 0.2, -0.6 - 0.2)
    # the curve at (1.2, 0.6) (S and W): an arc of radius 0.3 about its SW corner (0.9, 0.3)
    assert track.on_road(0.9 + 0.3 * math.cos(0.7), 0.3 + 0.3 * math.sin(0.7))
    assert not track.on_road(0.9 + 0.05, 0.3 + 0.05)  # the curve's inside corner is grass


def test_circle_of_curves() -> None:
    track = loop()
    line = track.centerline()
    assert np.allclose(line[0], line[-1]) and np.allclose(line[0], [0.3, 0.0])
    assert np.allclose(np.hypot(*(line - [0.3, 0.3]).T), 0.3, atol=1e-9)
    assert track.lap_length() == pytest.approx(2 * math.pi * 0.3, rel=1e-3)
    # the start's yaw picks the direction: pi drives the circle clockwise
    back = loop(start=[0.3, 0.0, math.pi]).centerline()
    assert back[3, 0] < back[0, 0]


def test_open_track_ends_where_the_road_does() -> None:
    track = parse_track({"tile_size": 0.5, "road_width": 0.2, "start": [0.0, 0.0, 0.0],
                         "tile": [{"kind": "straight", "col": c, "row": 0} for c in range(3)]}, "open.toml")
    line = track.centerline()
    assert np.allclose(line[0], [0.0, 0.0]) and np.allclose(line[-1], [1.25, 0.0])
    assert track.lap_length() == pytest.approx(1.25)
    assert track.name == "open"


def test_a_crossing_is_driven_straight_through_twice() -> None:
    # a figure of eight: the route crosses the crossing once along x and once along y
    tiles = [("cross", 0, 0, 0), ("curve", 1, 0, 90), ("curve", 1, 1, 180), ("curve", 0, 1, 270),
             ("curve", 0, -1, 90), ("curve", -1, -1, 0), ("curve", -1, 0, 270)]
    track = parse_track({"tile_size": 0.6, "road_width": 0.3, "start": [0.0, 0.0, 0.0],
                         "tile": [{"kind": k, "col": c, "row": r, "rotation": rot} for k, c, r, rot in tiles]},
                        "eight.toml")
    route, closed = track.route()
    assert closed and [(t.col, t.row) for t, _, _ in route].count((0, 0)) == 2
    assert track.lap_length() == pytest.approx(2 * 0.6 + 6 * math.pi * 0.3 / 2, abs=1e-3)


BAD = [
    ({"tile_size": -1}, "tile_size"),
    ({"tile_size": math.nan}, "tile_size"),
    ({"road_width": 0.7}, "road_width"),
    ({"start": [0.0, 0.0]}, "start"),
    ({"start": [0.0, 0.0, math.inf]}, "start"),
    ({"start": [5.0, 5.0, 0.0]}, "start"),
    ({"start": [0.3, 0.0, math.pi / 2]}, "start"),  # across the road
    ({"tile": []}, "tile"),
    ({"tile": [{"kind": "cross", "col": c % 60, "row": c // 60} for c in range(2501)]}, "tile: a track needs 1 to"),
    ({"tile": [{"kind": "hairpin", "col": 0, "row": 0}]}, "tile[0].kind"),
    ({"tile": [{"kind": "straight", "col": 0, "row": 0, "rotation": 45}]}, "tile[0].rotation"),
    ({"tile": [{"kind": "straight", "col": 0, "row": 0, "look": "desert"}]}, "tile[0].look"),
    ({"tile": [{"kind": "straight", "col": 0.5, "row": 0}]}, "tile[0].col"),
    ({"tile": [{"kind": "straight", "col": 0, "row": 0, "colour": "red"}]}, "tile[0]"),
    ({"tile": LOOP["tile"] + [{"kind": "cross", "col": 1, "row": 1}]}, "tile[4].col"),
    ({"sign": [{"kind": "stop", "x": 0, "y": 0, "yaw": 0, "stop_x": 5.0, "stop_y": 5.0}]}, "sign[0].stop_x"),
    ({"sign": [{"kind": "yield", "x": 0, "y": 0, "yaw": 0, "stop_x": 0.3, "stop_y": 0.0}]}, "sign[0].kind"),
    ({"sign": [{"kind": "stop", "x": 0, "y": 0, "yaw": 0, "stop_x": 0.3}]}, "sign[0]"),
    ({"sign": [{"kind": "stop", "x": 0, "y": 0, "yaw": 0, "size": 0, "stop_x": 0.3, "stop_y": 0}]}, "sign[0]"),
    ({"sign": [{"kind": "stop", "x": math.nan, "y": 0, "yaw": 0, "stop_x": 0.3, "stop_y": 0}]}, "sign[0]"),
    ({"lanes": 2}, "lanes"),
]


@pytest.mark.parametrize(("change", "field"), BAD)
def test_bad_layout_is_one_line_naming_the_file_and_field(change: dict, field: str) -> None:
    data = {**LOOP, "start": [0.3, 0.0, 0.0], **change}
    with pytest.raises(TrackError) as info:
        parse_track(data, "bad.toml")
    text = str(info.value)
    assert text.startswith("bad.toml: ") and field in text and "\n" not in text


def test_a_route_into_a_t_by_its_stem_is_refused() -> None:
    tiles = [{"kind": "straight", "col": 0, "row": 0, "rotation": 90},
             {"kind": "t", "col": 0, "row": 1, "rotation": 180}]  # W, S, E: the stem south
    with pytest.raises(TrackError, match=r"bad.toml: tile\[1\]: the route enters this T by its stem"):
        parse_track({"tile_size": 0.6, "road_width": 0.3, "start": [0.0, 0.0, math.pi / 2], "tile": tiles},
                    "bad.toml")


def test_bad_files_and_world_keys(tmp_path: Path) -> None:
    (tmp_path / "broken.toml").write_text("tile_size = ")
    with pytest.raises(TrackError, match=r"broken\.toml: not valid TOML"):
        load_track(str(tmp_path / "broken.toml"))
    with pytest.raises(TrackError, match="no such track layout"):
        load_track(str(tmp_path / "missing.toml"))
    with pytest.raises(TrackError, match="no track layout of that name"):
        load_track("no-such-track")
    # a world's relative path is taken from the world file's folder; errors name the layout file
    (tmp_path / "w.toml").write_text('track = "broken.toml"\n')
    with pytest.raises(ConfigError, match=re.escape(f"{tmp_path}/broken.toml: not valid TOML")):
        load_world(str(tmp_path / "w.toml"))
    (tmp_path / "ok.toml").write_text('tile_size = 0.6\nroad_width = 0.3\n'
                                      '[[tile]]\nkind = "straight"\ncol = 0\nrow = 0\n')
    (tmp_path / "w2.toml").write_text('track = "./ok.toml"\n')
    world = load_world(str(tmp_path / "w2.toml"))
    assert world.track is not None and world.track.name == "ok"
    (tmp_path / "w3.toml").write_text("track = 3\n")
    with pytest.raises(ConfigError, match=r"w3\.toml: track: must be the name"):
        load_world(str(tmp_path / "w3.toml"))
    assert load_world("lab").track is None
