"""What `icefloe calibrate` measures besides the lens: the marker detector's corner inset (which makes every
range long) from a ChArUco board of the robot's own dictionary, and the capture latency from a turn in
front of a board; both written to the calibration file and used by the camera service. Rendered frames
and synthetic data, no processes: about 5 s."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icefloe import config as config_mod
from icefloe.errors import ConfigError
from icefloe.services.camera.detection import Detector
from icefloe.services.camera.frames import camera_info
from icefloe.services.camera.sources import Retimed
from icefloe.sim.camera import CameraRenderer, true_intrinsics
from icefloe.vision import calibration as cal
from icefloe.vision.geometry import (
    CameraCalibration,
    Intrinsics,
    MarkerInset,
    Mount,
    load_calibration,
    load_extras,
    save_calibration,
)
from icefloe.worldmap import load_world

LAB_BOARD = cal.Board(5, 4, 0.08, "charuco", 0.06, "DICT_4X4_50", 40)
"""The calibration world's third board: the lab's own dictionary, ids 40-49 (deploy/worlds/calibration.toml)."""


def range_errors(inset: MarkerInset) -> np.ndarray:
    """Relative range errors of the lab's markers 0.5-2 m away, the robot at rest at 100 random poses, the
    detector given the true lens and ``inset``."""
    cfg = config_mod.parse({"sim": {"profile": "ideal"}})  # the inset is measured in the ideal picture
    world = load_world("lab")
    renderer = CameraRenderer.of_robot(cfg, seed=4)
    detector = Detector(cfg.camera.dictionary, true_intrinsics(cfg), Mount.from_config(cfg.camera), world.sizes(),
                        0.12, inset)
    rng = np.random.default_rng(11)
    errors = []
    for _ in range(100):
        x, y, theta = rng.uniform(-1.2, 1.2), rng.uniform(-1.2, 1.2), rng.uniform(-math.pi, math.pi)
        image, truth = renderer.render(x, y, theta)
        found = {lm.id: lm for lm in detector.detect(image)}
        for t in truth:
            lo, hi = t.corners.min(axis=0), t.corners.max(axis=0)
            if 0.5 <= t.range <= 2.0 and lo.min() > 10 and hi[0] < 630 and hi[1] < 470 and t.id in found:
                errors.append((found[t.id].range - t.range) / t.range)
    return np.array(errors)


def test_the_measured_inset_takes_the_range_bias_away():
    """The robot looks at the calibration world's ChArUco board of DICT_4X4_50 from 20 places (as
    `calibrate --drive` does); `measure_inset` fits the corners' inset; the lab's markers detected with
    it undone are no longer long. Measured (ideal profile): inset 0.003 + 6.2 / side px (0.23 px at 27 px)
    from 194 sightings, 0.037 px about the fit; range error mean +0.58 % -> -0.05 %, p50 0.61 % -> 0.15 %,
    37 sightings (150 poses: +0.66 % -> 0.00 %, p50 0.63 % -> 0.19 %, 58 sightings)."""
    cfg = config_mod.parse({"sim": {"world": "calibration", "profile": "ideal"}})  # as range_errors
    renderer = CameraRenderer.of_robot(cfg, seed=7)
    finder = cal.Finder(LAB_BOARD)
    views = [v for back in (0.0, 0.15, 0.3, 0.45) for turn in (0, 7, -7, 14, -14)
             if (v := finder.find(renderer.render(0.0, -back, math.pi / 2 + math.radians(turn))[0])) is not None]
    assert len(views) >= 15
    fit = cal.measure_inset(views, cal.with_intrinsics(views, true_intrinsics(cfg)))
    assert fit is not None
    print(f"\ninset {fit.inset.px:.3f} + {fit.inset.px2:.2f} / side px from {fit.markers} sightings "
          f"({fit.sides[0]:.0f}-{fit.sides[1]:.0f} px), {fit.residual:.3f} px about the fit")
    assert 0.1 < fit.inset.at(27) < 0.4 and fit.residual < 0.1
    before, after = range_errors(MarkerInset()), range_errors(fit.inset)
    print(f"range error mean {100 * before.mean():+.2f} % -> {100 * after.mean():+.2f} %, p50 "
          f"{100 * np.median(abs(before)):.2f} % -> {100 * np.median(abs(after)):.2f} % ({len(after)} sightings)")
    assert len(after) >= 30
    assert before.mean() > 0.004
    assert abs(after.mean()) < 0.002 and np.median(abs(after)) < 0.004


def test_a_chessboard_or_too_few_markers_measure_no_inset():
    view = cal.View(np.zeros((6, 1, 2), np.float32), np.zeros((6, 3), np.float32))
    result = cal.Calibration(Intrinsics.nominal(500, 640, 480), 0.1, [0.1], [(np.zeros(3), np.array([0, 0, 1.0]))])
    assert cal.measure_inset([view], result) is None


def test_undo_moves_each_edge_out_by_the_inset():
    square = np.array([[100.0, 100.0], [140.0, 100.0], [140.0, 140.0], [100.0, 140.0]])
    out = MarkerInset(0.5, 0.0).undo(square)
    assert out == pytest.approx(np.array([[99.5, 99.5], [140.5, 99.5], [140.5, 140.5], [99.5, 140.5]]))
    assert MarkerInset(0.0, 20.0).undo(square[::-1]) == pytest.approx(out[::-1])  # 20 px² at 40 px: 0.5 px
    assert MarkerInset().undo(square) is square
    assert MarkerInset(0.1, 5.0).at(25) == pytest.approx(0.3)


def test_the_extras_go_into_the_calibration_file_and_come_back(tmp_path):
    path = tmp_path / "cam.yaml"
    lens = Intrinsics.nominal(510, 640, 480)
    save_calibration(path, lens, 0.2, CameraCalibration(MarkerInset(0.01, 6.0), 0.052))
    assert load_extras(path) == CameraCalibration(MarkerInset(0.01, 6.0), 0.052)
    assert load_calibration(path, 640, 480).camera_matrix[0, 0] == 510
    save_calibration(path, lens, 0.2)  # a file from before the extras: none measured
    assert load_extras(path) == CameraCalibration()
    bad = tmp_path / "bad.yaml"
    bad.write_text(path.read_text().replace("rms_reprojection_error_px", "capture_latency_s: -1.0\n"
                                            "rms_reprojection_error_px"))
    with pytest.raises(ConfigError, match="capture_latency_s"):
        load_extras(bad)


def test_the_latency_is_the_shift_that_lines_the_board_up_with_odometry():
    """A sway of ±0.2 rad at 0.3 Hz; the board's yaw is a constant minus the heading at the exposure, which
    is 52 ms before the frame's stamp; odometry's turn 3 % long (an uncalibrated track); 0.2° of noise."""
    rng = np.random.default_rng(3)
    t_odo = np.arange(0.0, 6.0, 0.005)
    heading = 0.2 * np.sin(2 * math.pi * 0.3 * t_odo)
    headings = [(round(t * 1e9), 1.03 * h) for t, h in zip(t_odo, heading, strict=True)]
    stamps = np.arange(0.5, 5.5, 1 / 30)
    yaw = 1.0 - 0.2 * np.sin(2 * math.pi * 0.3 * (stamps - 0.052)) + rng.normal(0, math.radians(0.2), len(stamps))
    frames = [(round(s * 1e9), float(y)) for s, y in zip(stamps, yaw, strict=True)]
    fit = cal.fit_latency(frames, headings)
    assert fit is not None
    assert fit.latency_s == pytest.approx(0.052, abs=0.004)
    assert fit.gain == pytest.approx(-1 / 1.03, rel=0.02)
    assert cal.fit_latency(frames[:5], headings) is None


class Frames:
    def read(self) -> tuple[int, np.ndarray]:
        return 1_000_000_000, np.zeros((2, 2, 3), np.uint8)

    def close(self) -> None:
        pass


def test_the_camera_takes_the_latency_off_its_stamps_and_says_so():
    assert Retimed(Frames(), 52_000_000).read()[0] == 948_000_000
    cam = config_mod.parse({}).camera
    assert camera_info(cam, Intrinsics.from_config(cam), 0.052).capture_latency_s == 0.052
