"""The shipped ``sim`` robot is a calibrated PenguinPi: its camera's calibration file
(deploy/robots/sim-camera.yaml) and its ``[geometry]`` are what the project's calibration code finds for
the realistic robot now, so nobody edits them by hand. Remake them (docs/sim.md, "The shipped robot"):

    .venv/bin/python -m icefloe.sim.camera_calibration --robot sim --out deploy/robots/sim-camera.yaml
    .venv/bin/python -m icefloe.sim.wheel_calibration --robot sim

Pure computation, no processes: under a second.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from icefloe import config as config_mod
from icefloe.sim import camera_calibration, realism, wheel_calibration
from icefloe.vision.geometry import load_calibration, load_extras

SHIPPED = Path(__file__).resolve().parent.parent / "deploy" / "robots" / "sim-camera.yaml"


def test_the_shipped_camera_calibration_is_what_the_calibration_finds_now(tmp_path: Path) -> None:
    """Same seed, same code: the same file but for floating point (an OpenCV release may move a
    fit a little); the tolerances are a tenth of what the lens is off from the truth's."""
    config = config_mod.load("sim", credentials=False)
    assert Path(config.camera.calibration).resolve() == SHIPPED.resolve(), "sim.toml's [camera] calibration"
    fresh = tmp_path / "camera.yaml"
    assert camera_calibration.main(["--robot", "sim", "--out", str(fresh)]) == 0  # the command docs/sim.md gives
    width, height = config.camera.width, config.camera.height
    now, shipped = load_calibration(fresh, width, height), load_calibration(SHIPPED, width, height)
    np.testing.assert_allclose(shipped.camera_matrix, now.camera_matrix, atol=0.2)
    np.testing.assert_allclose(shipped.dist_coeffs, now.dist_coeffs, atol=0.005)
    for side in (15, 30, 60):
        assert load_extras(SHIPPED).inset.at(side) == pytest.approx(load_extras(fresh).inset.at(side), abs=0.02)


def test_the_shipped_geometry_is_what_the_wheel_calibration_finds_now(capsys: pytest.CaptureFixture[str]) -> None:
    """Measured: wheel_diameter 0.06382 m (the true wheels' mean 0.0640, a start's slip in it), track
    0.15804 m spinning at 1.59 rad/s (0.1535 / (1 - 0.02 x 1.59) = 0.1585)."""
    config = config_mod.load("sim", credentials=False)
    assert config.sim.profile == "realistic"
    found = wheel_calibration.calibrate_wheels(config)
    assert config.geometry.wheel_diameter == pytest.approx(found.wheel_diameter, abs=2e-5)
    assert config.geometry.track == pytest.approx(found.track, abs=2e-5)
    assert wheel_calibration.main(["--robot", "sim"]) == 0  # the command docs/sim.md gives prints what sim.toml says
    printed = capsys.readouterr().out
    assert f"wheel_diameter = {config.geometry.wheel_diameter:.5f}" in printed
    assert f"track = {config.geometry.track:.5f}" in printed
    true = realism.wheels(config)
    # and it found the true wheels, not the drawing's
    assert found.wheel_diameter == pytest.approx((true.diameter_left + true.diameter_right) / 2, rel=0.006)
    assert found.track == pytest.approx(true.track / (1 - true.slip_turn * found.turn_rate), rel=0.01)
