"""The simulator's cameras see a track world's road (sim/floor.py, sim/camera.py, sim/overhead.py):
the painted lines where the floor plane's geometry puts them, a stop sign where it stands, nothing
of the road above the horizon, an obstacle hiding the road behind it; the overhead camera too.
Frames are rendered without noise or lighting changes, so a pixel's colour is the texture's."""

from __future__ import annotations

import math

import cv2
import msgspec
import numpy as np
import pytest

from icefloe import config as config_mod
from icefloe.sim import floor
from icefloe.sim.camera import CameraRenderer, true_intrinsics
from icefloe.sim.floor import PAINT, SIGN_RED, edge_line_offset, floor_texture
from icefloe.sim.overhead import OverheadRenderer
from icefloe.track import parse_track
from icefloe.vision.geometry import Intrinsics, Mount
from icefloe.vision.overhead import CameraPose, project
from icefloe.worldmap import Box, WorldMap, load_world

MOUNT = Mount(0.05, 0.0, 0.10, 0.0)
"""The shipped robot's camera: 5 cm ahead of its centre, 10 cm up, looking ahead (config defaults)."""
START = (-0.9, -0.6, 0.0)
"""On the bottom road of the shipped loop (its centre at y = -0.6), driving +x, 0.3 m before the
start line: the edge lines run straight ahead, the T's junction is 0.9 m ahead."""


@pytest.fixture(scope="module")
def world() -> WorldMap:
    return load_world("track")


def renderer(world: WorldMap) -> CameraRenderer:
    return CameraRenderer(world, Intrinsics.nominal(500.0, 640, 480), MOUNT, noise=0.0, lighting=0.0)


def pixel_of(r: CameraRenderer, pose: tuple[float, float, float], point: tuple[float, float, float]) -> np.ndarray:
    """Where the world point (m) lands in the frame seen from ``pose``."""
    _, lens, world_from_camera = r._camera(*pose)
    return r._frame_pixels((np.array([point]) - lens) @ world_from_camera)[0]


def test_edge_lines_are_where_the_floor_plane_puts_them(world: WorldMap) -> None:
    r = renderer(world)
    image, _ = r.render(*START)
    assert world.track is not None
    offset = edge_line_offset(world.track)
    for ahead in (0.3, 0.5, 0.7):  # (0.8 ahead on the left is the T's opening)
        for side in (-1, 1):
            u, v = pixel_of(r, START, (START[0] + ahead, START[1] + side * offset, 0.0))
            white = (image[round(v)] > np.array(PAINT) - 30).all(axis=1)
            assert white[round(u)], (ahead, side)
            left, right = round(u), round(u)  # the run of white pixels around the projection
            while left > 0 and white[left - 1]:
                left -= 1
            while right < 639 and white[right + 1]:
                right += 1
            # the line's middle, within a pixel of the floor's texture (2 mm) seen from there
            tolerance = max(1.0, 500.0 * 0.002 / (ahead - MOUNT.x))
            assert abs((left + right) / 2 - u) <= tolerance, (ahead, side, left, right, u)
    # asphalt between the lines, the pavement beyond them
    u, v = pixel_of(r, START, (START[0] + 0.5, START[1] + 0.08, 0.0))
    assert image[round(v), round(u)].max() < 90
    u, v = pixel_of(r, START, (START[0] + 0.5, START[1] - 0.25, 0.0))
    assert image[round(v), round(u)].min() > 140


def test_nothing_of_the_road_above_the_horizon(world: WorldMap) -> None:
    plain = renderer(msgspec.structs.replace(world, track=None))
    grey, _ = plain.render(*START)
    image, _ = renderer(world).render(*START)
    horizon = 240  # a level camera: the principal point's row (cy = 239.5)
    assert (image[:horizon] == grey[:horizon]).all()
    assert not (image[horizon + 20:] == grey[horizon + 20:]).all()
    # turned away from every tile, the camera sees the floor as a world without a track
    away = (-1.6, -0.9, -math.pi / 2)
    assert (renderer(world).render(*away)[0] == plain.render(*away)[0]).all()


def test_a_stop_sign_stands_where_the_layout_puts_it(world: WorldMap) -> None:
    assert world.track is not None
    sign = world.track.signs[0]
    pose = (sign.x + 0.6, sign.stop_y, math.pi)  # on the road 0.6 m before it, facing it
    r = renderer(world)
    image, _ = r.render(*pose)
    u, v = pixel_of(r, pose, (sign.x, sign.y, sign.size * 0.8))
    b, g, red = image[round(v), round(u)].astype(int)
    assert red > 150 and g < 80 and b < 80  # the octagon's red, above the letters
    # the face's square corner is outside the octagon: the floor shows there, not red
    corner = r._sign_quads[0][0] + 0.1 * (r._sign_quads[0][2] - r._sign_quads[0][0])
    u, v = pixel_of(r, pose, tuple(corner))
    b, g, red = image[round(v), round(u)].astype(int)
    assert not (red > 150 and g < 80)
    # from behind, the sign is not drawn
    behind = (sign.x - 0.6, sign.y, 0.0)
    u, v = pixel_of(r, behind, (sign.x, sign.y, sign.size * 0.8))
    b, g, red = r.render(*behind)[0][round(v), round(u)].astype(int)
    assert not (red > 150 and g < 80)
    assert tuple(SIGN_RED) == (35, 30, 200)


def test_an_obstacle_hides_the_road_and_the_sign(world: WorldMap) -> None:
    assert world.track is not None
    box = Box(x=START[0] + 0.5, y=START[1], length=0.1, width=0.2, height=0.3)
    blocked = renderer(msgspec.structs.replace(world, obstacles=(box,)))
    image, _ = blocked.render(*START)
    open_image, _ = renderer(world).render(*START)
    u, v = pixel_of(blocked, START, (START[0] + 1.0, START[1] - edge_line_offset(world.track), 0.0))
    assert (open_image[round(v), round(u)] > np.array(PAINT) - 30).all()  # the right edge line, 1 m ahead
    seen = image[round(v), round(u)]
    assert seen[0] == seen[1] == seen[2] and int(seen[0]) in blocked._obstacle_greys  # the box's face
    sign = world.track.signs[0]
    pose = (sign.x + 0.6, sign.stop_y, math.pi)
    lens_x = pose[0] - MOUNT.x  # facing -x
    across = pose[1] + (sign.y - pose[1]) * (lens_x - (sign.x + 0.3)) / (lens_x - sign.x)  # where the ray passes
    wall = Box(x=sign.x + 0.3, y=across, length=0.05, width=0.1, height=0.3)
    hidden = renderer(msgspec.structs.replace(world, obstacles=(wall,)))
    u, v = pixel_of(hidden, pose, (sign.x, sign.y, sign.size * 0.8))
    _, g, red = hidden.render(*pose)[0][round(v), round(u)].astype(int)
    assert not (red > 150 and g < 80)


def test_the_overhead_camera_sees_the_road(world: WorldMap) -> None:
    intrinsics = Intrinsics.nominal(410.0, 1280, 720)
    pose = CameraPose.looking_down(0.0, 0.0, 2.5)
    image = OverheadRenderer(world, intrinsics, pose, "DICT_4X4_50", noise=0.0, lighting=0.0).render([])
    urban, rural, bare = project(intrinsics, pose, np.array([[-0.6, -0.6 + 0.08, 0.0], [-0.6, 0.6 + 0.08, 0.0],
                                                              [-0.6, 0.0, 0.0]])).round().astype(int)
    assert image[urban[1], urban[0]].max() < 90                        # asphalt
    b, g, r = image[rural[1], rural[0]].astype(int)
    assert r > g > b                                                   # dirt
    b, g, r = image[bare[1], bare[0]].astype(int)
    assert b == g == r                                                 # no tile: the plain floor


def test_floor_texture_is_seeded_and_bounded(world: WorldMap, monkeypatch: pytest.MonkeyPatch) -> None:
    assert world.track is not None
    a, transform = floor_texture(world.track, seed=3)
    assert (a == floor_texture(world.track, seed=3)[0]).all()
    assert not (a == floor_texture(world.track, seed=4)[0]).all()
    # the texture pixel's centre maps to the world: the first pixel is the top-left tile's corner
    assert np.allclose(transform @ [-0.5, -0.5, 1], [-1.5, 0.9, 1])
    big = parse_track({"tile_size": 0.6, "road_width": 0.3, "start": [0.0, 0.0, 0.0],
                       "tile": [{"kind": "straight", "col": c, "row": 0} for c in range(40)]}, "long.toml")
    monkeypatch.setattr(floor, "MAX_PIXELS", 200_000)
    texture, _ = floor_texture(big)
    assert texture.shape[0] * texture.shape[1] <= 200_000


def test_the_lens_noise_and_blur_apply_to_the_road(world: WorldMap) -> None:
    assert world.track is not None
    k = Intrinsics.nominal(500.0, 640, 480).camera_matrix
    bent = Intrinsics(k, np.array([-0.3, 0.1, 0.0, 0.0, 0.0]), 640, 480)
    clean, _ = renderer(world).render(*START)
    image, _ = CameraRenderer(world, bent, MOUNT, noise=3.0, lighting=0.15, blur=1.0).render(*START)
    assert image.shape == (480, 640, 3) and not (image == clean).all()
    # barrel distortion pulls the edge line towards the frame's centre; it is drawn where the lens puts it
    line = (START[0] + 0.3, START[1] - edge_line_offset(world.track), 0.0)
    u, _ = pixel_of(renderer(world), START, line)
    lens = CameraRenderer(world, bent, MOUNT, noise=0.0, lighting=0.0)
    bent_u, bent_v = pixel_of(lens, START, line)
    assert bent_u < u - 10
    white = (lens.render(*START)[0][round(bent_v)] > np.array(PAINT) - 40).all(axis=1)
    assert white[round(bent_u)]


def test_a_track_world_in_the_realistic_profile_gets_the_lens_light_blur_noise_and_jpeg() -> None:
    """The realistic profile's effects apply to a track's colour frame as to a grey one: the road's
    edge line is drawn where the true (barrel) lens puts it, not where a pinhole would; the frame
    is still in colour (the grass); auto exposure chose a shutter; a turn smears the frame; the
    picture repeats with its seed."""
    config = config_mod.parse({"sim": {"profile": "realistic", "world": "track"}})
    world = load_world(config.sim.world)
    assert world.track is not None
    real = CameraRenderer.of_robot(config, seed=3)
    image, _ = real.render(*START)
    assert image.shape == (480, 640, 3)
    assert real.exposure[0] > 0  # a shutter time: auto exposure ran
    # the same pose through the same lens without distortion: the pinhole's projection of the line
    lens = true_intrinsics(config)
    assert lens.dist_coeffs.ravel()[0] < 0  # barrel
    pinhole = CameraRenderer(world, Intrinsics(lens.camera_matrix, np.zeros(5), 640, 480), MOUNT,
                             noise=0.0, lighting=0.0)
    line = (START[0] + 0.3, START[1] - edge_line_offset(world.track), 0.0)  # the right edge line
    u, _ = pixel_of(pinhole, START, line)
    bent_u, bent_v = pixel_of(real, START, line)
    assert bent_u < u - 10  # barrel distortion pulls it towards the centre
    row = image[round(bent_v)].astype(int).sum(axis=1)
    # the line (white) where the lens puts it, brighter than the asphalt beside it; not where a pinhole would
    assert row[round(bent_u)] > row[round(bent_u) - 40] + 200, (row[round(bent_u)], row[round(bent_u) - 40])
    white = row > row[round(bent_u)] - 100
    left = right = round(bent_u)  # the run of white pixels around the bent projection
    while left > 0 and white[left - 1]:
        left -= 1
    while right < 639 and white[right + 1]:
        right += 1
    middle = (left + right) / 2  # measured: 589.5 for the lens's 589.0, the pinhole's 602.4
    assert abs(middle - bent_u) < 3, (left, right, bent_u)
    assert u - middle > 10, (left, right, u)
    # colour: the rural tiles' grass is greener than it is red
    _, g, r = image[240:].reshape(-1, 3).astype(int).T
    assert ((g - r) > 40).sum() > 1000
    # a turn at 1.5 rad/s during the shutter smears the frame sideways
    turning, _ = CameraRenderer.of_robot(config, seed=3).render(*START, turn_rate=1.5)
    sharp = cv2.Laplacian(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), cv2.CV_64F).var()
    smeared = cv2.Laplacian(cv2.cvtColor(turning, cv2.COLOR_BGR2GRAY), cv2.CV_64F).var()
    assert smeared < 0.7 * sharp
    # seeded: the same seed the same picture (noise and JPEG included), another seed another
    assert np.array_equal(CameraRenderer.of_robot(config, seed=3).render(*START)[0], image)
    assert not np.array_equal(CameraRenderer.of_robot(config, seed=4).render(*START)[0], image)
