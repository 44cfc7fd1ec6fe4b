"""The simulated camera draws the world's obstacles, and they hide what is behind them (pure: no
bus). The camera service's own detector is run on the rendered frames: what a box hides, a
student's detector cannot find either. ~5 s. The render time with obstacles is measured in
``bench/camera_render.py`` (docs/sim.md)."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from icefloe import config as config_mod
from icefloe.services.camera.detection import make_detector
from icefloe.sim.camera import NEAR, CameraRenderer, clip_near, obstacle_faces, true_intrinsics
from icefloe.vision.geometry import Mount
from icefloe.worldmap import WorldMap, load_world, parse_world

BOX = {"kind": "box", "x": 1.5, "y": -0.15, "length": 0.3, "width": 0.4, "height": 0.3}
"""A box 1.35 to 1.65 m ahead of the robot at the origin, y from -0.35 to 0.05 m."""
MARKERS = [
    # on the box's near face (a print stuck on it, 1 mm proud): seen
    {"id": 1, "x": 1.349, "y": -0.25, "z": 0.15, "size": 0.12, "yaw": math.pi},
    # straight behind the box: hidden
    {"id": 2, "x": 2.2, "y": -0.05, "z": 0.12, "size": 0.12, "yaw": math.pi},
    # behind the box's left edge: partly hidden
    {"id": 3, "x": 2.2, "y": 0.12, "z": 0.12, "size": 0.12, "yaw": math.pi},
    # beside the box, nearer: seen
    {"id": 4, "x": 1.2, "y": 0.4, "z": 0.10, "size": 0.12, "yaw": math.pi},
]


def world_of(*obstacles: dict) -> WorldMap:
    return parse_world({"name": "occlusion", "marker": MARKERS, "obstacle": list(obstacles)}, "occlusion.toml")


def seen(world: WorldMap, x: float, y: float, theta: float) -> tuple[list[int], list[int]]:
    """(ids in the renderer's ground truth, ids the camera service's detector finds), each sorted."""
    cfg = config_mod.load()
    renderer = CameraRenderer(world, true_intrinsics(cfg), Mount.from_config(cfg.camera), cfg.camera.dictionary,
                              seed=3)
    image, truth = renderer.render(x, y, theta)
    found = make_detector(cfg).detect(image)
    return sorted(t.id for t in truth), sorted(lm.id for lm in found)


def test_a_marker_behind_a_box_is_hidden_and_one_on_it_or_in_front_is_seen() -> None:
    truth, found = seen(world_of(BOX), 0.0, 0.0, 0.0)
    assert truth == [1, 4], truth
    assert found == [1, 4], found  # 2 behind the box, 3 half behind it: the detector finds neither
    # the control: without the box, the camera sees all four
    truth, found = seen(world_of(), 0.0, 0.0, 0.0)
    assert truth == found == [1, 2, 3, 4], (truth, found)


def test_a_box_drawn_in_front_of_the_robot_covers_the_picture_it_fills() -> None:
    """Nose to a box (5 cm from its face): the middle of the frame is the box's face, one flat grey,
    not the wall and floor drawn behind it (no noise: the pixels are the shade)."""
    cfg = config_mod.load()
    wall = {"kind": "wall", "x0": 0.3, "y0": -2.0, "x1": 0.3, "y1": 2.0, "thickness": 0.05, "height": 0.5}
    renderer = CameraRenderer(world_of(wall), true_intrinsics(cfg), Mount.from_config(cfg.camera),
                              cfg.camera.dictionary, noise=0.0, lighting=0.0)
    image, truth = renderer.render(0.3 - 0.025 - 0.05 - cfg.camera.mount_x, 0.0, 0.0)
    assert truth == []  # the four markers are all behind the wall
    middle = image[image.shape[0] // 4: 3 * image.shape[0] // 4, image.shape[1] // 4: 3 * image.shape[1] // 4]
    assert np.ptp(middle) <= 1, np.unique(middle)


def test_in_the_lab_the_crate_hides_marker_9() -> None:
    """From (-0.6, 0.2) looking at marker 9 on the south wall, the crate stands in between."""
    lab = load_world("lab")
    pose = (-0.6, 0.2, math.atan2(-2.0 - 0.2, -1.2 + 0.6))
    truth, found = seen(lab, *pose)
    assert 9 not in truth and 9 not in found, (truth, found)
    truth, found = seen(msgspec.structs.replace(lab, obstacles=()), *pose)
    assert 9 in truth and 9 in found, (truth, found)


def test_obstacle_faces_turn_outwards_and_clipping_keeps_what_is_in_front() -> None:
    corners, normals, greys = obstacle_faces(world_of({**BOX, "yaw": 0.7}))
    assert corners.shape == (5, 4, 3) and normals.shape == (5, 3) and greys.shape == (5,)
    centre = np.array([BOX["x"], BOX["y"], BOX["height"] / 2])
    for face, normal in zip(corners, normals, strict=True):
        assert np.linalg.norm(normal) == pytest.approx(1.0)
        assert (face.mean(axis=0) - centre) @ normal > 0  # outwards
        assert np.allclose((face - face[0]) @ normal, 0.0)  # flat
    assert greys.min() >= 90 and greys.max() <= 180  # no face black, none white
    # a quad from 1 m behind the lens to 1 m in front of it: the part in front, from NEAR on
    quad = np.array([[-1.0, 0.0, -1.0], [1.0, 0.0, -1.0], [1.0, 0.0, 1.0], [-1.0, 0.0, 1.0]])
    clipped = clip_near(quad)
    assert len(clipped) == 4 and clipped[:, 2].min() == pytest.approx(NEAR) and clipped[:, 2].max() == 1.0
    assert len(clip_near(quad - [0.0, 0.0, 2.0])) == 0
