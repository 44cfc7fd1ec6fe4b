"""The lab's overhead camera, pure logic: the simulated picture, calibration from the floor, and
the robots' poses against the truth they were drawn at (no processes; a few seconds)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icefloe import config as config_mod
from icefloe.errors import ConfigError
from icefloe.services.extloc import locate
from icefloe.sim.overhead import OverheadRenderer, RobotView
from icefloe.vision.geometry import Intrinsics
from icefloe.vision.overhead import CameraPose, flat_square_corners, project
from icefloe.worldmap import load_world, parse_world

DICTIONARY = "DICT_4X4_100"


def lab_robots(n: int, seed: int = 3) -> list[RobotView]:
    """``n`` robots spread over the 4 m x 4 m lab, headings at random."""
    rng = np.random.default_rng(seed)
    return [RobotView(20 + i, 0.16, 0.12, -1.2 + (i % 5) * 0.6 + rng.uniform(-0.1, 0.1),
                      -1.2 + (i // 5) * 0.6 + rng.uniform(-0.1, 0.1), rng.uniform(-math.pi, math.pi))
            for i in range(n)]


@pytest.fixture(scope="module")
def camera() -> tuple[Intrinsics, CameraPose, OverheadRenderer]:
    intrinsics = Intrinsics.nominal(410.0, 1280, 720)
    truth = CameraPose.looking_down(0.03, -0.02, 2.5, yaw=0.01, tilt=0.02)  # hung a little off
    return intrinsics, truth, OverheadRenderer(load_world("lab"), intrinsics, truth, DICTIONARY)


def test_overhead_sim_camera_draws_the_floor_markers_and_every_robot_where_they_are(camera) -> None:
    intrinsics, truth, renderer = camera
    robots = lab_robots(20)
    image = renderer.render(robots)
    assert image.shape == (720, 1280, 3)
    seen = locate.find_markers(locate.make_detector(DICTIONARY), image)
    world = load_world("lab")
    assert set(seen) == {f.id for f in world.floor_markers} | {r.marker_id for r in robots}
    for robot in robots:  # each corner within a fraction of a pixel of where the geometry puts it
        expected = project(intrinsics, truth, flat_square_corners(robot.x, robot.y, robot.marker_height,
                                                                  robot.theta, robot.marker_size / 2))
        assert np.abs(seen[robot.marker_id] - expected).max() < 0.5, robot


def test_overhead_calibration_finds_the_camera_from_the_floor_markers(camera) -> None:
    intrinsics, truth, renderer = camera
    image = renderer.render(lab_robots(3))
    seen = locate.find_markers(locate.make_detector(DICTIONARY), image)
    found = locate.calibrate(intrinsics, load_world("lab"), seen)
    assert np.linalg.norm(found.pose.lens - truth.lens) < 0.01  # the lens within 1 cm
    assert found.rms_px < 0.5 and found.rms_floor_m < 0.003
    assert len(found.markers) == 8


def test_overhead_calibration_with_too_few_floor_markers_says_which_it_saw(camera) -> None:
    intrinsics, _, renderer = camera
    seen = locate.find_markers(locate.make_detector(DICTIONARY), renderer.render([]))
    with pytest.raises(locate.CalibrationFailed, match=r"1 of world lab's 8 floor markers in view"):
        locate.calibrate(intrinsics, load_world("lab"), {80: seen[80]})


def test_overhead_locator_gives_each_robot_its_true_pose(camera) -> None:
    intrinsics, _, renderer = camera
    world = load_world("lab")
    detector = locate.make_detector(DICTIONARY)
    pose = locate.calibrate(intrinsics, world, locate.find_markers(detector, renderer.render([]))).pose
    robots = lab_robots(20)
    tops = {r.marker_id: locate.TopMarker(f"r{r.marker_id}", r.marker_id, r.marker_size, r.marker_height)
            for r in robots}
    fixes = locate.Locator(DICTIONARY, intrinsics, pose, tops).locate(renderer.render(robots))
    assert sorted(f.robot for f in fixes) == sorted(t.robot for t in tops.values())
    for fix in fixes:
        robot = next(r for r in robots if f"r{r.marker_id}" == fix.robot)
        assert math.hypot(fix.x - robot.x, fix.y - robot.y) < 0.005, fix
        assert abs(math.remainder(fix.theta - robot.theta, math.tau)) < math.radians(2), fix
        assert 0 < fix.sigma_xy < 0.01 and 0 < fix.sigma_theta < 0.1


def test_overhead_locator_sees_nothing_of_a_robot_out_of_view(camera) -> None:
    intrinsics, truth, renderer = camera
    away = RobotView(20, 0.16, 0.12, 5.0, 0.0, 0.0)  # beyond the wall
    tops = {20: locate.TopMarker("r20", 20, 0.16, 0.12)}
    assert locate.Locator(DICTIONARY, intrinsics, truth, tops).locate(renderer.render([away])) == []


def test_overhead_top_marker_config_is_checked_and_named() -> None:
    with pytest.raises(ConfigError, match=r"r\.toml: extloc\.marker_size"):
        config_mod.parse({"extloc": {"marker_size": 0}}, "r.toml")
    with pytest.raises(ConfigError, match=r"r\.toml: extloc\.marker_id"):
        config_mod.parse({"extloc": {"marker_id": -5}}, "r.toml")
    with pytest.raises(ConfigError, match=r"lab\.toml: \[overhead\]"):
        config_mod.parse({"overhead": {"lens": 3}}, "lab.toml")
    with pytest.raises(ConfigError, match=r"w\.toml: floor_marker\[1\]\.id: id 80 is already used"):
        parse_world({"floor_marker": [{"id": 80, "x": 0, "y": 0, "size": 0.2},
                                      {"id": 80, "x": 1, "y": 0, "size": 0.2}]}, "w.toml")
    world = load_world("lab")
    with pytest.raises(ConfigError, match=r"b: extloc\.marker_id: 20 is robot a's too"):
        locate.top_markers([locate.TopMarker("a", 20, 0.16, 0.1), locate.TopMarker("b", 20, 0.16, 0.1)], world)
    with pytest.raises(ConfigError, match=r"a: extloc\.marker_id: 80 is a floor marker's id in world lab"):
        locate.top_markers([locate.TopMarker("a", 80, 0.16, 0.1)], world)
    with pytest.raises(ConfigError, match=r"a: extloc\.marker_id: 100 is not in DICT_4X4_100 \(overhead\.dictionary"):
        locate.top_markers([locate.TopMarker("a", 100, 0.16, 0.1)], world)
    with pytest.raises(ConfigError, match=r"overhead\.dictionary: 'DICT_NOPE' is not an OpenCV ArUco dictionary"):
        locate.top_markers([locate.TopMarker("a", 1, 0.16, 0.1)], world, "DICT_NOPE")
    with pytest.raises(ConfigError, match=r"world lab: floor marker 87 is not in DICT_4X4_50"):
        locate.top_markers([locate.TopMarker("a", 1, 0.16, 0.1)], world, "DICT_4X4_50")


def test_overhead_calibrate_command_from_an_image_file(camera, tmp_path, capsys) -> None:
    import cv2

    from icefloe.cli import main
    from icefloe.vision.overhead import load_pose

    _, truth, renderer = camera
    picture = tmp_path / "overhead.png"
    cv2.imwrite(str(picture), renderer.render(lab_robots(5)))
    lab = tmp_path / "lab.toml"
    lab.write_text(f'name = "lab"\n[overhead]\nrobots = ["sim"]\npose = "{tmp_path / "pose.yaml"}"\n')
    assert main(["extloc", "calibrate", str(lab), "--image", str(picture)]) == 0
    out = capsys.readouterr().out
    assert "floor markers used: 80, 81, 82, 83, 84, 85, 86, 87 of 8 in world lab" in out
    assert "px RMS" in out and "mm RMS" in out
    pose = load_pose(tmp_path / "pose.yaml", 1280, 720)
    assert np.linalg.norm(pose.lens - truth.lens) < 0.01
    # From a live frame of the lab's camera (here the simulated one, hung 5 cm off centre).
    live = tmp_path / "live.toml"
    live.write_text('name = "lab"\n[overhead]\nrobots = ["sim"]\nsim_x = 0.05\nsim_tilt = 0.02\n')
    assert main(["extloc", "calibrate", str(live), "--out", str(tmp_path / "live.yaml")]) == 0
    assert "camera lens at x 0.050 m, y 0.000 m, 2.500 m above the floor" in capsys.readouterr().out
    # A picture without floor markers: one line saying what it saw, exit status 2.
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((720, 1280, 3), 128, np.uint8))
    assert main(["extloc", "calibrate", str(lab), "--image", str(blank)]) == 2
    assert "0 of world lab's 8 floor markers in view" in capsys.readouterr().err


def test_overhead_lens_distortion_is_undone_before_the_floor() -> None:
    """With a calibration's distortion (as `icefloe calibrate` writes it), a pixel goes back to the
    very point on the plane it was projected from; ignoring the distortion would be centimetres off."""
    from icefloe.vision.overhead import to_plane

    k = np.array([[420.0, 0.0, 645.0], [0.0, 418.0, 355.0], [0.0, 0.0, 1.0]])
    lens = Intrinsics(k, np.array([-0.28, 0.09, 0.001, -0.0005, -0.01]), 1280, 720)
    pose = CameraPose.looking_down(0.1, -0.05, 2.5, yaw=0.2, tilt=0.03)
    points = np.array([[x, y, 0.12] for x in np.linspace(-1.8, 1.8, 7) for y in np.linspace(-1.8, 1.8, 7)])
    pixels = project(lens, pose, points)
    assert np.abs(to_plane(lens, pose, pixels, 0.12) - points).max() < 1e-6
    pinhole = Intrinsics(k, np.zeros(5), 1280, 720)
    assert np.abs(to_plane(pinhole, pose, pixels, 0.12) - points).max() > 0.05
