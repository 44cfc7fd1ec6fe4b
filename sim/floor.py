"""What a track's floor and signs look like: textures made once from a layout (`icefloe.track`).

`floor_texture` paints the tiles seen from above, one texture for the whole track: urban tiles
are dark asphalt with white edge lines and a dashed white centre line on a pale concrete
pavement; rural tiles a light dirt road on grass, without lines (as the RVSS workshop's urban
and rural tiles). A stop line crosses the road at each sign's ``stop_x, stop_y``. Grain comes
from a seeded generator, so a test can replay a frame. Pixels with no tile are transparent
(alpha 0): the plain floor shows there.

`stop_sign_texture` is a red octagon with a white rim and "STOP", transparent outside it.

The cameras (`icefloe.sim.camera`, `icefloe.sim.overhead`) warp these onto the floor plane and
onto each sign's quad with a homography.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np

from icefloe.track import Track, centre_piece, road_mask

PX_PER_M = 500
"""The floor texture's resolution: 2 mm a pixel (the robot's camera, 0.1 m above the floor, sees
the nearest floor at 0.4 mm a pixel, so nearer than ~1 m the texture is magnified)."""
MAX_PIXELS = 24_000_000
"""A big layout's texture is made coarser to stay within this (~100 MB with alpha)."""
LINE_WIDTH = 0.015
"""A painted line's width, m."""
EDGE_INSET = 0.015
"""From the road's edge to its edge line, m."""
DASH = 0.05
"""The centre line's dashes and gaps, m each (three of each on a 0.6 m tile's half)."""
STOP_LINE = 0.03
"""The stop line's width, m."""

# BGR
ASPHALT, PAVEMENT, PAINT = (62, 60, 58), (165, 168, 170), (235, 238, 240)
DIRT, GRASS = (95, 150, 190), (55, 135, 70)
SIGN_RED = (35, 30, 200)


def edge_line_offset(track: Track) -> float:
    """From the road's centre to the middle of an urban edge line, m."""
    return track.road_width / 2 - EDGE_INSET - LINE_WIDTH / 2


def floor_texture(track: Track, seed: int = 1, px_per_m: float = PX_PER_M) -> tuple[np.ndarray, np.ndarray]:
    """The track's floor seen from above (BGRA, uint8: row 0 at the largest y, so +y is up as on a
    map) and ``world_from_texture``: the 3x3 affine taking texture pixel (column, row, 1) to the
    world point (x, y, 1), m, of the pixel's centre."""
    ts, half = track.tile_size, track.tile_size / 2
    cols, rows = [t.col for t in track.tiles], [t.row for t in track.tiles]
    x0, y1 = min(cols) * ts - half, max(rows) * ts + half
    width_m, height_m = (max(cols) - min(cols) + 1) * ts, (max(rows) - min(rows) + 1) * ts
    px_per_m = min(px_per_m, math.sqrt(MAX_PIXELS / (width_m * height_m)))
    w, h = max(1, int(width_m * px_per_m)), max(1, int(height_m * px_per_m))
    m = width_m / w  # m per pixel (the same along y, up to rounding)
    world_from_texture = np.array([[m, 0.0, x0 + m / 2], [0.0, -height_m / h, y1 - height_m / h / 2],
                                   [0.0, 0.0, 1.0]])
    xs = world_from_texture[0, 0] * np.arange(w) + world_from_texture[0, 2]
    ys = world_from_texture[1, 1] * np.arange(h) + world_from_texture[1, 2]
    road = np.zeros((h, w), bool)
    urban = np.zeros((h, w), bool)
    tiled = np.zeros((h, w), bool)
    for tile in track.tiles:
        c = np.flatnonzero(np.abs(xs - tile.col * ts) <= half)
        r = np.flatnonzero(np.abs(ys - tile.row * ts) <= half)
        if not len(c) or not len(r):
            continue
        box = np.s_[r[0]:r[-1] + 1, c[0]:c[-1] + 1]
        u, v = track.local(tile, xs[c][None, :], ys[r][:, None])
        road[box] = road_mask(tile.kind, u, v, half, track.road_width / 2)
        tiled[box] = True
        urban[box] = tile.look == "urban"
    rng = np.random.default_rng(seed)
    grain = rng.normal(0.0, 1.0, (h, w, 1)).astype(np.float32)
    texture = np.empty((h, w, 3), np.float32)
    for mask, colour, amount in ((urban & ~road, PAVEMENT, 6), (urban & road, ASPHALT, 5),
                                 (~urban & ~road, GRASS, 14), (~urban & road, DIRT, 10)):
        texture[mask] = np.float32(colour) + amount * grain[mask]
    # Urban edge lines: where the distance to the road's edge is within the line's band.
    # (distanceTransform measures centre to centre: the edge itself lies half a pixel nearer)
    inside = (cv2.distanceTransform(road.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE) - 0.5) * m
    edge = urban & (inside > EDGE_INSET) & (inside <= EDGE_INSET + LINE_WIDTH)
    paint = np.zeros((h, w), np.uint8)
    paint[edge] = 1
    texture_from_world = np.linalg.inv(world_from_texture)
    to_px = lambda points: (points @ texture_from_world[:2, :2].T + texture_from_world[:2, 2])  # noqa: E731
    thick = max(1, round(LINE_WIDTH / m))
    for tile in track.tiles:
        if tile.look != "urban":
            continue
        for a, b in _centre_pieces(tile.kind):
            piece = centre_piece(tile.kind, a, b, half)
            # skip the junction's square, where roads cross (no line is painted across it)
            keep = ~((np.abs(piece[:, 0]) < track.road_width / 2) & (np.abs(piece[:, 1]) < track.road_width / 2)) \
                if tile.kind in ("t", "cross") else np.ones(len(piece), bool)
            along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(piece, axis=0).T))])
            dash = (along % (2 * DASH)) < DASH
            world = _turn(piece, tile.rotation) + np.array([tile.col * ts, tile.row * ts])
            px = np.round(to_px(world) * 16).astype(np.int32)
            for i in range(len(piece) - 1):
                if dash[i] and keep[i] and keep[i + 1]:
                    cv2.line(paint, tuple(px[i]), tuple(px[i + 1]), 1, thick, cv2.LINE_8, shift=4)
    for sign in track.signs:  # a stop line across the road, along the sign's face
        across = np.array([-math.sin(sign.yaw), math.cos(sign.yaw)]) * track.road_width / 2
        ends = to_px(np.array([[sign.stop_x, sign.stop_y]]) + np.array([-across, across]))
        cv2.line(paint, tuple(np.round(ends[0] * 16).astype(int)), tuple(np.round(ends[1] * 16).astype(int)), 1,
                 max(1, round(STOP_LINE / m)), cv2.LINE_8, shift=4)
    painted = (paint > 0) & road
    texture[painted] = np.float32(PAINT) + 4 * grain[painted]
    alpha = np.where(tiled, 255, 0).astype(np.uint8)
    bgra = np.dstack([texture.clip(0, 255).astype(np.uint8), alpha])
    return bgra, world_from_texture


@functools.lru_cache(maxsize=2)
def shared_floor_texture(track: Track, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """`floor_texture`, made once per track and seed in a process and shared, read-only: the
    robot's and the overhead camera's renderers (and a test's several) draw the same floor."""
    texture, world_from_texture = floor_texture(track, seed)
    texture.flags.writeable = world_from_texture.flags.writeable = False
    return texture, world_from_texture


def _centre_pieces(kind: str) -> tuple[tuple[int, int], ...]:
    """The centre lines of a tile at rotation 0, as (from edge, to edge) pairs."""
    if kind in ("straight",):
        return ((2, 0),)
    if kind in ("curve", "corner"):
        return ((0, 1),)
    if kind == "t":
        return ((2, 0), (1, 3))  # the stem: from N to S, its southern half falls in the junction or
    return ((2, 0), (3, 1))      # the road beyond the T's bar (clipped by the road mask: no road there)


def _turn(points: np.ndarray, rotation: int) -> np.ndarray:
    a = math.radians(rotation)
    c, s = round(math.cos(a)), round(math.sin(a))
    return points @ np.array([[c, s], [-s, c]])


def stop_sign_texture(side_px: int) -> np.ndarray:
    """A stop sign's face (BGRA, side_px square): a red octagon, a white rim, "STOP" in white;
    transparent outside the octagon."""
    n = max(16, side_px)
    texture = np.zeros((n, n, 4), np.uint8)
    centre = (n - 1) / 2
    angles = np.radians(22.5 + 45 * np.arange(8))
    octagon = lambda r: np.round((centre + r * np.stack([np.cos(angles), np.sin(angles)], 1)) * 16).astype(np.int32)  # noqa: E731
    cv2.fillConvexPoly(texture, octagon(n / 2 / math.cos(math.pi / 8) - 0.5), (255, 255, 255, 255), cv2.LINE_AA, 4)
    cv2.fillConvexPoly(texture, octagon(0.88 * n / 2 / math.cos(math.pi / 8)), (*SIGN_RED, 255), cv2.LINE_AA, 4)
    scale = n / 130
    (tw, th), _ = cv2.getTextSize("STOP", cv2.FONT_HERSHEY_DUPLEX, scale, max(1, round(3 * scale)))
    cv2.putText(texture, "STOP", (round(centre - tw / 2), round(centre + th / 2)), cv2.FONT_HERSHEY_DUPLEX, scale,
                (255, 255, 255, 255), max(1, round(3 * scale)), cv2.LINE_AA)
    return texture
