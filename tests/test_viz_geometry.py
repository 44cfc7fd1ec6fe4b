"""Pure helpers of viz: no Zenoh, no viewer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icefloe.schemas import messages as m
from icefloe.services.viz.decimate import Decimator
from icefloe.services.viz.logging_rr import covariance_ellipse, obstacle_outlines, ray_ends, unpack_oled
from icefloe.worldmap import Box, Wall


def test_decimator_keeps_one_in_five_of_100_hz_at_20_hz_and_restarts_when_time_goes_back():
    d = Decimator(20)
    kept = [t for t in range(0, 1_000_000_000, 10_000_000) if d.keep(t)]
    assert len(kept) == 20
    assert d.keep(0)  # the stamp went backwards: start again


def test_covariance_ellipse_has_the_95_percent_radii_along_the_axes():
    outline = covariance_ellipse(1.0, 2.0, [0.04, 0, 0, 0, 0.01, 0, 0, 0, 0.1])
    offsets = outline - [1.0, 2.0]
    assert np.allclose(outline[0], outline[-1])
    assert math.isclose(np.abs(offsets[:, 0]).max(), math.sqrt(5.991 * 0.04), rel_tol=1e-3)
    assert math.isclose(np.abs(offsets[:, 1]).max(), math.sqrt(5.991 * 0.01), rel_tol=1e-2)
    with pytest.raises(ValueError):
        covariance_ellipse(0, 0, [1.0, 0.0])


def test_ray_ends_point_to_the_landmark_in_the_map():
    ends = ray_ends(1.0, 0.0, math.pi / 2, [m.Landmark(id=3, range=2.0, bearing=-math.pi / 2)])
    assert np.allclose(ends, [[3.0, 0.0]])


def test_oled_unpacks_msb_first_and_rejects_short_frames():
    image = unpack_oled(16, 2, bytes([0b1000_0000, 0, 0, 0b0000_0001]))
    assert image[0, 0] == 255 and image[0, 1] == 0 and image[1, 15] == 255 and image.sum() == 2 * 255
    with pytest.raises(ValueError):
        unpack_oled(128, 32, bytes(10))


def test_obstacle_outline_is_the_rotated_closed_rectangle() -> None:
    (box,) = obstacle_outlines([Box(x=1.0, y=2.0, length=0.4, width=0.2, yaw=math.pi / 2).rectangle()])
    assert box.shape == (5, 2) and np.allclose(box[0], box[-1])
    assert np.allclose(sorted(map(tuple, box[:4].round(6))), [(0.9, 1.8), (0.9, 2.2), (1.1, 1.8), (1.1, 2.2)])
    (wall,) = obstacle_outlines([Wall(x0=0.0, y0=0.0, x1=2.0, y1=0.0, thickness=0.1).rectangle()])
    assert np.allclose(wall.min(axis=0), [0.0, -0.05]) and np.allclose(wall.max(axis=0), [2.0, 0.05])
