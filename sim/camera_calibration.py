"""The simulated camera calibrated offline, as `icefloe calibrate` would calibrate it on the robot, for
benches and tests that need a calibrated camera without a minute of driving in front of a board.

The simulated camera renders the calibration world's boards (deploy/worlds/calibration.toml) through
the profile's true lens and picture (`icefloe.sim.realism`); `icefloe.vision.calibration` finds the lens
from the chessboard (the ideal profile's lens is the one the camera believes: kept) and the marker
detector's corner inset from the DICT_4X4_50 ChArUco board, from the places `calibrate --drive` looks
from. The capture latency is not measured: that needs the robot's own turn (`calibrate --drive`).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import msgspec

from icefloe import config as config_mod
from icefloe.config import RobotConfig
from icefloe.vision import calibration as cal
from icefloe.vision.geometry import CameraCalibration, Intrinsics, MarkerInset, save_calibration

from .camera import CameraRenderer, true_intrinsics

CHESSBOARD_POSES = [(-back, 0.0, math.radians(turn)) for back in (0.0, 0.15, 0.3) for turn in (0, 7, -7, 14, -14)]
"""Where the robot looks at the chessboard from (0.5 m ahead of the start): x m, y m, heading rad."""
CHARUCO_POSES = [(0.0, -back, math.pi / 2 + math.radians(turn)) for back in (0.0, 0.15, 0.3, 0.45)
                 for turn in (0, 7, -7, 14, -14)]
"""... and at the DICT_4X4_50 ChArUco board (0.65 m to the start's left)."""
CHESSBOARD = cal.Board(10, 7, 0.025)
LAB_CHARUCO = cal.Board(5, 4, 0.08, "charuco", 0.06, "DICT_4X4_50", 40)


def calibrate_camera(config: RobotConfig, path: Path, seed: int = 1) -> str:
    """Calibrate ``config``'s simulated camera (its profile's lens and picture, in the calibration world)
    and write the calibration file at ``path``, as `icefloe calibrate` writes it; a line of what it found."""
    config = msgspec.structs.replace(config, sim=msgspec.structs.replace(config.sim, world="calibration"))
    renderer = CameraRenderer.of_robot(config, seed=seed)
    lens, rms = Intrinsics.from_config(config.camera), None
    if config.sim.profile != "ideal":
        finder = cal.Finder(CHESSBOARD)
        views = [v for pose in CHESSBOARD_POSES if (v := finder.find(renderer.render(*pose)[0])) is not None]
        result = cal.calibrate(views, lens.width, lens.height)
        lens, rms = result.intrinsics, result.rms
    finder = cal.Finder(LAB_CHARUCO)
    views = [v for pose in CHARUCO_POSES if (v := finder.find(renderer.render(*pose)[0])) is not None]
    fit = cal.measure_inset(views, cal.with_intrinsics(views, lens))
    inset = fit.inset if fit is not None else MarkerInset()
    save_calibration(path, lens, rms, CameraCalibration(inset, 0.0))
    truth, k = true_intrinsics(config).camera_matrix, lens.camera_matrix
    return (f"lens fx {k[0, 0]:.1f} (true {truth[0, 0]:.1f}) fy {k[1, 1]:.1f} ({truth[1, 1]:.1f}) "
            f"k1 {lens.dist_coeffs[0]:+.3f}; marker inset {inset.at(30):.3f} px at 30 px")


SHIPPED_SEED = 1
"""The seed the shipped ``sim`` robot's calibration file is made with (its renders' noise and light)."""


def calibrate_realistic(robot: str, out: Path, seed: int = SHIPPED_SEED) -> str:
    """Calibrate robot ``robot``'s camera in the realistic profile, whatever its config's profile: the
    shipped calibration is a real PenguinPi's, and in the ideal profile the simulated lens is the one its
    camera believes (the file's) anyway. Writes ``out``; a line of what it found."""
    config = config_mod.load(robot, credentials=False)
    config = msgspec.structs.replace(config, sim=msgspec.structs.replace(config.sim, profile="realistic"))
    return calibrate_camera(config, out, seed=seed)


def main(argv: list[str] | None = None) -> int:
    """``python -m icefloe.sim.camera_calibration --robot sim --out deploy/robots/sim-camera.yaml``:
    remake the shipped robot's calibration file (tests/test_shipped_calibration.py checks it is current)."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--robot", default="sim", help="the robot config (a name or a path) whose camera to calibrate")
    parser.add_argument("--out", required=True, type=Path, help="the calibration file to write (OpenCV YAML)")
    parser.add_argument("--seed", type=int, default=SHIPPED_SEED, help="seed of the renders' noise and light")
    args = parser.parse_args(argv)
    print(f"{args.out}: {calibrate_realistic(args.robot, args.out, args.seed)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
