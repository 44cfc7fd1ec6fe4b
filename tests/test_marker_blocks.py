"""Marker blocks: one ArUco id on several faces of a cube (``[[block]]`` in a world file).

The world map checks them (ids unique per landmark; the faces of a block share one), the
simulator renders each face, the camera's detector finds each face it sees (an id twice in one
frame), and the localizer takes each block as one landmark at the cube's centre. Pure (no bus):
the simulator's renderer, the camera service's detector and the localizer's own state. ~10 s.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import msgspec
import pytest

from icefloe import config as config_mod
from icefloe.errors import ConfigError
from icefloe.estimation.blocks import to_centres
from icefloe.estimation.localizer import Localizer
from icefloe.schemas import messages as m
from icefloe.services.camera.detection import Detector
from icefloe.sim.camera import CameraRenderer
from icefloe.vision.geometry import Intrinsics, Mount
from icefloe.worldmap import load_world, parse_world

BLOCK = {"id": 12, "x": 1.0, "y": 0.0, "z": 0.10, "side": 0.16, "size": 0.12, "yaw": 0.0}


def world_of(**tables: list[dict]) -> dict:
    return {"name": "blocks", **tables}


# --------------------------------------------------------------------------- the world file


def test_a_block_is_one_landmark_at_its_centre_with_a_marker_on_each_face() -> None:
    world = parse_world(world_of(block=[BLOCK], marker=[{"id": 3, "x": 2.0, "y": 0.0, "z": 0.1, "size": 0.15,
                                                         "yaw": math.pi}]), "blocks.toml")
    faces = [f for f in world.faces() if f.id == 12]
    assert len(faces) == 4 and len(world.faces()) == 5
    # Each face half an edge from the centre, facing out: +x, +y, -x, -y.
    assert [(round(f.x, 6), round(f.y, 6), round(math.cos(f.yaw)), round(math.sin(f.yaw))) for f in faces] == [
        (1.08, 0.0, 1, 0), (1.0, 0.08, 0, 1), (0.92, 0.0, -1, 0), (1.0, -0.08, 0, -1)]
    assert world.landmarks() == {3: (2.0, 0.0), 12: (1.0, 0.0)}
    assert world.sizes() == {3: 0.15, 12: 0.12}
    assert world.block(12).side == 0.16 and world.marker(12) is None
    two = parse_world(world_of(block=[{**BLOCK, "faces": 2}]), "two.toml")
    assert len(two.faces()) == 2


@pytest.mark.parametrize(("tables", "error"), [
    ({"marker": [{"id": 12, "x": 0, "y": 0, "z": 0.1, "size": 0.1, "yaw": 0}], "block": [BLOCK]},
     "w.toml: block[0].id: id 12 is already used by marker[0] (one id is one landmark: to print it on "
     "several faces, make it a [[block]])"),
    ({"block": [BLOCK, {**BLOCK, "x": 3.0}]}, "w.toml: block[1].id: id 12 is already used by block[0]"),
    ({"block": [{**BLOCK, "faces": 5}]}, "faces"),
    ({"block": [{**BLOCK, "size": 0.2}]}, "`size` (0.2 m) must be less than `side` (0.16 m)"),
    ({"block": [{**BLOCK, "x": math.nan}]}, "`x` must be a finite number"),
    ({"block": [{k: v for k, v in BLOCK.items() if k != "side"}]}, "side"),
    ({"block": [{**BLOCK, "colour": "red"}]}, "colour"),
])
def test_bad_blocks_are_refused_with_a_named_error(tables: dict, error: str) -> None:
    with pytest.raises(ConfigError) as refused:
        parse_world(world_of(**tables), "w.toml")
    message = str(refused.value)
    assert message.startswith("w.toml") and error in message, message
    assert "\n" not in message


# --------------------------------------------------------------------------- camera and localizer


def camera_parts(world) -> tuple[CameraRenderer, Detector, Mount]:  # type: ignore[no-untyped-def]
    cam = config_mod.load().camera
    intrinsics, mount = Intrinsics.from_config(cam), Mount.from_config(cam)
    renderer = CameraRenderer(world, intrinsics, mount, cam.dictionary, seed=3)
    return renderer, Detector(cam.dictionary, intrinsics, mount, world.sizes(), cam.marker_size), mount


@pytest.mark.parametrize(("block_yaw", "faces_seen"), [(0.0, 1), (math.pi / 4, 2)])
def test_the_camera_sees_each_face_and_the_localizer_one_landmark_at_the_centre(block_yaw: float,
                                                                                faces_seen: int) -> None:
    """Head-on, one face; at a corner, two faces with the same id in one frame. Either way the
    localizer's sighting is the cube's centre, 1 m straight ahead of the robot."""
    world = parse_world(world_of(block=[{**BLOCK, "yaw": block_yaw}]), "w.toml")
    renderer, detector, mount = camera_parts(world)
    image, truth = renderer.render(0.0, 0.0, 0.0)
    assert [t.id for t in truth] == [12] * faces_seen  # the simulator drew them all in view
    found = detector.detect(image)
    assert [lm.id for lm in found] == [12] * faces_seen
    # A face is nearer than the centre: half an edge head-on, less at a corner.
    assert all(0.9 < lm.range < 0.97 for lm in found), [lm.range for lm in found]
    [centre] = to_centres(found, {12: BLOCK["side"] / 2}, mount)
    assert centre.id == 12
    assert centre.range == pytest.approx(1.0, abs=0.02)
    assert abs(math.degrees(centre.bearing)) < 1.0
    # Without the marker's pose (another detector): along the line of sight; exact head-on.
    [rough] = to_centres([msgspec.structs.replace(lm, position=[], rotation=[]) for lm in found][:1],
                         {12: BLOCK["side"] / 2}, mount)
    assert rough.range == pytest.approx(1.0, abs=0.05)


def test_the_localizer_finds_the_robot_from_blocks_seen_by_the_simulated_camera(tmp_path: Path) -> None:
    """A world of two blocks and a marker; the localizer starts from the landmarks of one frame
    (``init = "landmarks"``) and must put the robot where the simulator has it."""
    world_file = tmp_path / "blocks.toml"
    world_file.write_text(
        "[[block]]\nid = 12\nx = 1.2\ny = 0.5\nz = 0.1\nside = 0.16\nsize = 0.12\nyaw = 0.3\n\n"
        "[[block]]\nid = 13\nx = 1.4\ny = -0.6\nz = 0.1\nside = 0.16\nsize = 0.12\nyaw = 0.0\n\n"
        "[[marker]]\nid = 4\nx = 2.0\ny = 0.0\nz = 0.1\nsize = 0.15\nyaw = 3.141593\n")
    world = load_world(str(world_file))
    config = config_mod.load()
    config = msgspec.structs.replace(config, localizer=msgspec.structs.replace(
        config.localizer, world=str(world_file), init="landmarks"))
    renderer, detector, _ = camera_parts(world)
    true_pose = (0.1, -0.05, 0.08)
    image, _ = renderer.render(*true_pose)
    found = detector.detect(image)
    assert {lm.id for lm in found} == {4, 12, 13}
    localizer = Localizer(config, logging.getLogger("test"))
    assert localizer.on_landmarks(m.Landmarks(stamp=1, landmarks=found))
    estimate = localizer.estimate()
    assert estimate.x == pytest.approx(true_pose[0], abs=0.03)
    assert estimate.y == pytest.approx(true_pose[1], abs=0.03)
    assert estimate.theta == pytest.approx(true_pose[2], abs=math.radians(2))


def test_the_shipped_blocks_world_every_block_seen_lands_on_its_centre() -> None:
    """deploy/worlds/blocks.toml from the middle of the arena, turning round: each block sighting
    (one or two faces) becomes one sighting of its cube's centre, within 3 cm and 1.5°."""
    world = load_world("blocks")
    renderer, detector, mount = camera_parts(world)
    half = {b.id: b.side / 2 for b in world.blocks}
    seen = set()
    for step in range(8):
        theta = step * math.pi / 4
        image, _ = renderer.render(0.0, 0.0, theta)
        for lm in to_centres(detector.detect(image), half, mount):
            if lm.id not in half:
                continue
            seen.add(lm.id)
            bx, by = world.landmarks()[lm.id]
            assert lm.range == pytest.approx(math.hypot(bx, by), abs=0.03), lm.id
            want = math.atan2(by, bx) - theta
            assert abs(math.degrees(math.remainder(lm.bearing - want, math.tau))) < 1.5, lm.id
    assert seen == set(half)
