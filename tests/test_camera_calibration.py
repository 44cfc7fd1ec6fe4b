"""Camera calibration: boards rendered by the simulated camera, found and solved by OpenCV.

The simulator's lens is known exactly here (``[sim.lens]``), so what the calibration finds is
compared with the truth, not with itself. The end-to-end run against real processes (the
simulator, the camera service, ``icefloe calibrate --auto --drive``) is in test_calibrate_cli.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from icefloe import config as config_mod
from icefloe.cli.calibrate import calibration_paths, point_config_at
from icefloe.errors import ConfigError
from icefloe.sim import realism
from icefloe.sim.camera import CameraRenderer, true_intrinsics
from icefloe.vision import calibration as cal
from icefloe.vision.geometry import Mount, load_calibration, save_calibration
from icefloe.worldmap import parse_world

LENS = {"fx": 540.0, "fy": 536.0, "cx": 327.0, "cy": 244.0, "distortion": [-0.15, 0.09, 0.0, 0.0, 0.0]}
CHESSBOARD = {"kind": "chessboard", "columns": 10, "rows": 7, "square": 0.025, "x": 0.55, "y": 0.0, "z": 0.12,
              "yaw": math.pi, "tilt": 0.35}
CHARUCO = {"kind": "charuco", "columns": 7, "rows": 5, "square": 0.04, "marker": 0.03, "x": 0.6, "y": 0.0,
           "z": 0.12, "yaw": math.pi, "tilt": 0.35}


def renderer(board: dict) -> CameraRenderer:
    cfg = config_mod.parse({"sim": {"lens": LENS}})
    world = parse_world({"board": [board]}, "calibration.toml")
    return CameraRenderer(world, true_intrinsics(cfg), Mount.from_config(cfg.camera), seed=7)


POSES = [(-back, 0.0, math.radians(turn)) for back in (0.0, 0.15, 0.3) for turn in (0, 7, -7, 14, -14)]
"""What `icefloe calibrate --drive` does: back up, turn the board across the picture."""


def test_the_rendered_chessboard_is_found_where_the_lens_puts_it():
    r = renderer(CHESSBOARD)
    finder = cal.Finder(cal.Board(10, 7, 0.025))
    errors = []
    for pose in POSES[:5]:
        view = finder.find(r.render(*pose)[0])
        truth = r.board_corners(*pose)[0]
        assert view is not None and truth is not None
        found = view.image_points.reshape(-1, 2)
        # The corners may come in either order (the board looks the same turned half round).
        errors.append(min(np.linalg.norm(found - truth, axis=1).mean(),
                          np.linalg.norm(found[::-1] - truth, axis=1).mean()))
    print(f"corner error against the truth: mean {np.mean(errors):.3f} px, worst view {max(errors):.3f} px")
    assert max(errors) < 0.15
    assert r.board_corners(0.0, 0.0, math.pi) == [None]  # from behind: nothing


@pytest.mark.parametrize(("board", "printed"), [(CHESSBOARD, cal.Board(10, 7, 0.025)),
                                                (CHARUCO, cal.Board(7, 5, 0.04, "charuco", 0.03))],
                         ids=["chessboard", "charuco"])
def test_calibration_recovers_the_simulated_lens(board, printed):
    r = renderer(board)
    finder = cal.Finder(printed)
    views = [v for pose in POSES if (v := finder.find(r.render(*pose)[0])) is not None]
    assert len(views) >= 10
    result = cal.calibrate(views, 640, 480)
    k, d = result.intrinsics.camera_matrix, result.intrinsics.dist_coeffs
    print(f"{board['kind']}: {len(views)} views, RMS {result.rms:.3f} px; fx {k[0, 0]:.1f} (true 540) "
          f"fy {k[1, 1]:.1f} (536) cx {k[0, 2]:.1f} (327) cy {k[1, 2]:.1f} (244) k1 {d[0]:.3f} (-0.15) "
          f"k2 {d[1]:.3f} (0.09)")
    # A camera on a robot sees a standing board only turned about the vertical, from one height:
    # that pins the focal length down to about 1.5 % (a hand-held board, turned every way, does better).
    assert result.rms < 0.3
    assert k[0, 0] == pytest.approx(540, rel=0.03) and k[1, 1] == pytest.approx(536, rel=0.03)
    assert k[0, 2] == pytest.approx(327, abs=6) and k[1, 2] == pytest.approx(244, abs=8)
    assert d[0] == pytest.approx(-0.15, abs=0.03)
    assert max(result.view_errors) < 3 * result.rms + 0.1


def test_the_same_view_twice_is_not_new_but_a_turned_one_is():
    r = renderer(CHESSBOARD)
    finder = cal.Finder(cal.Board(10, 7, 0.025))
    a, b = (finder.find(r.render(*POSES[0])[0]) for _ in range(2))  # two frames, noise apart
    c = finder.find(r.render(*POSES[1])[0])
    assert a is not None and b is not None and c is not None
    assert cal.view_distance(a, b) < 1.0
    assert cal.view_distance(a, c) > 25.0
    flipped = cal.View(b.image_points[::-1].copy(), b.object_points)  # the other corner order
    assert cal.view_distance(a, flipped) < 1.0
    counts = cal.region_counts([a, c], 640, 480)
    assert counts.sum() >= 2 and counts[2].sum() == 0  # the board stands above the lens: bottom empty


def test_too_few_views_or_a_bad_board_are_refused():
    with pytest.raises(ValueError, match="at least 3 views"):
        cal.calibrate([], 640, 480)
    with pytest.raises(ValueError, match=r"marker: must be > 0 and smaller than the square \(0.04 m\)"):
        cal.Board(7, 5, 0.04, "charuco", 0.05)
    with pytest.raises(ValueError, match="dictionary: 'DICT_9X9' is not an OpenCV ArUco dictionary"):
        cal.Board(7, 5, 0.04, "charuco", 0.03, "DICT_9X9")
    with pytest.raises(ValueError, match="at least 3x3 squares"):
        cal.Board(2, 5, 0.04)


def test_the_config_is_pointed_at_the_calibration_keeping_its_text(tmp_path):
    cases = {
        "no camera table": ('name = "r1"\n# a comment\n', "\n[camera]\n"),
        "a camera table": ('name = "r1"\n\n[camera]  # the Pi camera\nsource = "picamera2"\n\n[power]\nlow_v = 6.9\n',
                           "source = \"picamera2\""),
        "a calibration already": ('name = "r1"\n[camera]\ncalibration = "/old.yaml"\nfps = 10.0\n', "fps = 10.0"),
    }
    for name, (text, kept) in cases.items():
        path = tmp_path / f"{name.replace(' ', '-')}.toml"
        path.write_text(text)
        target = tmp_path / "cam.yaml"
        point_config_at(path, target)
        new = path.read_text()
        assert kept in new and new.count("calibration =") == 1, name
        assert config_mod.load(path).camera.calibration == str(target), name
        assert "# a comment" in new or name != "no camera table"
    # A form we do not edit: refused, and the file is left as it was.
    dotted = tmp_path / "dotted.toml"
    dotted.write_text('name = "r1"\ncamera.calibration = "/old.yaml"\n')
    with pytest.raises(ConfigError, match=r"did not take|not valid TOML"):
        point_config_at(dotted, tmp_path / "cam.yaml")
    assert dotted.read_text() == 'name = "r1"\ncamera.calibration = "/old.yaml"\n'


def test_a_shipped_config_is_not_edited_but_extended_in_your_own_folder(tmp_path, monkeypatch):
    monkeypatch.setenv("ICEFLOE_CONFIG_DIR", str(tmp_path / "mine"))
    shipped = config_mod.load("sim-calibration")
    config_file, calibration = calibration_paths(shipped, None)
    assert config_file == tmp_path / "mine" / "robots" / "sim-calibration.toml"
    assert calibration == config_file.with_name("sim-calibration.camera.yaml")
    save_calibration(calibration, true_intrinsics(shipped), 0.1)
    point_config_at(config_file, calibration)
    mine = config_mod.load("sim-calibration")  # your own now comes first, over the shipped one
    assert mine.camera.calibration == str(calibration) and mine.sim.lens.fx == 540.0
    loaded = load_calibration(mine.camera.calibration, 640, 480)
    assert loaded.camera_matrix[0, 0] == 540.0


def test_calibration_recovers_the_realistic_profiles_lens_through_its_picture():
    """The realistic profile's lens (a little tilted too: p1, p2) drawn through its picture: uneven light,
    auto exposure, noise, the lens's softness, JPEG at 85. Measured: 15 views, RMS 0.067 px; fx 536.9
    (true 540), fy 533.6 (536), cx 327.1 (327), cy 246.3 (244), k1 -0.151 (-0.15), p2 -0.0011 (-0.0012)."""
    cfg = config_mod.parse({"sim": {"profile": "realistic"}})
    world = parse_world({"board": [CHESSBOARD]}, "calibration.toml")
    r = CameraRenderer(world, true_intrinsics(cfg), Mount.from_config(cfg.camera), seed=7,
                       picture=realism.picture(cfg))
    finder = cal.Finder(cal.Board(10, 7, 0.025))
    views = [v for pose in POSES if (v := finder.find(r.render(*pose)[0])) is not None]
    result = cal.calibrate(views, 640, 480)
    k, d = result.intrinsics.camera_matrix, result.intrinsics.dist_coeffs
    print(f"realistic: {len(views)} views, RMS {result.rms:.3f} px; fx {k[0, 0]:.1f} (true 540) fy {k[1, 1]:.1f} "
          f"(536) cx {k[0, 2]:.1f} (327) cy {k[1, 2]:.1f} (244) k1 {d[0]:.3f} (-0.15) k2 {d[1]:.3f} (0.09) "
          f"p1 {d[2]:.4f} (0.0008) p2 {d[3]:.4f} (-0.0012)")
    assert len(views) >= 10 and result.rms < 0.2
    assert k[0, 0] == pytest.approx(540, rel=0.03) and k[1, 1] == pytest.approx(536, rel=0.03)
    assert k[0, 2] == pytest.approx(327, abs=6) and k[1, 2] == pytest.approx(244, abs=8)
    assert d[0] == pytest.approx(-0.15, abs=0.03)
