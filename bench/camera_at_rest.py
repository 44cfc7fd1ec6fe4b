"""The camera's range errors at rest on rendered frames, and the localizer's error they make: per marker, and fused.

    .venv/bin/python bench/camera_at_rest.py [--pose X Y THETA] [--frames 30] [--poses 80] [--profile ideal]

Renders ``--frames`` frames (``--profile``'s picture and lens, `sim/camera.py`) of the lab from
``--pose`` (default: tests/test_localizer_at_rest.py's), finds the markers with the camera service's
detector (`make_detector`) as detected and with the marker inset undone (the calibration
`sim/camera_calibration.py` makes, as `icefloe calibrate` would; both with the lens it finds), and
prints each marker's mean range and bearing error against the truth, and
the pose the localizer's filter (`make_ekf`, started at the truth) settles at from them. The reference,
in the same run: the same solve from the markers' true corners, which must come out exact in the ideal
profile (the detector's geometry, the camera's mount and the filter add nothing of their own; in the
realistic one, what is left is the calibrated lens's error). Then ``--poses``
random places in the lab with two or more markers within 2.5 m: the fused position error's p50, p90
and max over them (10 frames each), every sighting's range error, and how far inside the black square
the detector put each edge (the mean of its two corners along its normal), by the refinement window
OpenCV takes from the marker's mean side and by how obliquely the marker is seen: what the
calibration's one inset per side (`MarkerInset`) stands for.
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import cv2
import msgspec
import numpy as np

from icefloe import config as config_mod
from icefloe.config import RobotConfig
from icefloe.estimation.ekf import Ekf
from icefloe.estimation.localizer import make_ekf
from icefloe.services.camera.detection import Detector, make_detector
from icefloe.sim.camera import CameraRenderer, Visible
from icefloe.sim.camera_calibration import calibrate_camera
from icefloe.vision.geometry import load_calibration, range_bearing, save_calibration

TEST_POSE = (1.0, 0.75, -0.785)
"""tests/test_localizer_at_rest.py's POSE: markers 1 and 0 at 1.25 and 2.19 m, 37 and 63 degrees from square on."""


def from_true_corners(detector: Detector, seen: Visible) -> tuple[float, float]:
    """Range and bearing the detector's geometry gives from a marker's true corners."""
    size = detector.sizes.get(seen.id, detector.default_size)
    corners = np.array([[-1, 1, 0], [1, 1, 0], [1, -1, 0], [-1, -1, 0]], float) * size / 2
    _, _, tvec = cv2.solvePnP(corners, seen.corners.astype(float), detector.k, detector.dist,
                              flags=cv2.SOLVEPNP_IPPE_SQUARE)
    return range_bearing(detector.mount.to_robot(tvec.ravel()))


def started_at(config: RobotConfig, pose: tuple[float, float, float]) -> Ekf:
    """The localizer's filter, started at ``pose`` with the config's sigmas."""
    x, y, theta = pose
    return make_ekf(msgspec.structs.replace(config, localizer=msgspec.structs.replace(
        config.localizer, initial_x=x, initial_y=y, initial_theta=theta)))


def at_pose(renderer: CameraRenderer, detectors: dict[str, Detector], config: RobotConfig,
            pose: tuple[float, float, float], frames: int) -> tuple[dict, dict[str, Ekf]]:
    """Per (way, marker id) the (range, bearing) errors of each frame, and each way's filter after them."""
    errors: dict[tuple[str, int], list[tuple[float, float]]] = {}
    filters = {way: started_at(config, pose) for way in ("true corners", *detectors)}
    for _ in range(frames):
        image, visible = renderer.render(*pose)
        truth = {v.id: v for v in visible}
        found = {way: [(lm.id, lm.range, lm.bearing) for lm in det.detect(image) if lm.id in truth]
                 for way, det in detectors.items()}
        found["true corners"] = [(v.id, *from_true_corners(detectors["as detected"], v)) for v in visible]
        for way, sightings in found.items():
            for marker, rng, bearing in sightings:
                filters[way].observe(marker, rng, bearing)
                errors.setdefault((way, marker), []).append((rng - truth[marker].range,
                                                             math.remainder(bearing - truth[marker].bearing, math.tau)))
    return errors, filters


def refinement_window(corners: np.ndarray) -> int:
    """The half-size of the window OpenCV's ArUco detector gives `cv2.cornerSubPix` for a marker, px:
    ``relativeCornerRefinmentWinSize`` (0.3) x its mean cell (mean side / 6 for 4x4 bits and the
    border), rounded, at least 1 and at most ``cornerRefinementWinSize`` (3, `robot_detector`)."""
    side = float(np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1).mean())
    return min(3, max(1, round(0.3 * side / 6)))


def edge_insets(detected: np.ndarray, true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per edge i (corner i to i + 1) of a marker: how far inside the true square the detected corners
    are along its inward normal (px, their mean), and its true length (px)."""
    edges = np.roll(true, -1, axis=0) - true
    lengths = np.linalg.norm(edges, axis=1)
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1) / lengths[:, None]
    inward = ((true.mean(axis=0) - (true + edges / 2)) * normals).sum(axis=1) > 0
    normals[~inward] *= -1
    miss = detected - true
    return np.array([(miss[i] + miss[(i + 1) % 4]) @ normals[i] / 2 for i in range(4)]), lengths


def pose_error(ekf: Ekf, pose: tuple[float, float, float]) -> tuple[float, float]:
    """(position error m, heading error rad) of the filter's pose."""
    x, y, theta = ekf.pose
    return math.hypot(x - pose[0], y - pose[1]), abs(math.remainder(theta - pose[2], math.tau))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--pose", type=float, nargs=3, default=TEST_POSE, metavar=("X", "Y", "THETA"),
                        help="where the robot stands: m, m, rad")
    parser.add_argument("--frames", type=int, default=30, help="frames rendered at the pose")
    parser.add_argument("--poses", type=int, default=80, help="random poses for the summary (0: none)")
    parser.add_argument("--profile", choices=("ideal", "realistic"), default="ideal", help="the simulator's profile")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    config = config_mod.parse({"sim": {"seed": 3, "profile": args.profile}})
    renderer = CameraRenderer.of_robot(config, seed=3)
    with tempfile.TemporaryDirectory() as tmp:
        undone_path, lens_path = Path(tmp) / "camera.yaml", Path(tmp) / "lens.yaml"
        print("calibrated:", calibrate_camera(config, undone_path, seed=7))
        save_calibration(lens_path, load_calibration(undone_path, config.camera.width, config.camera.height))

        def with_calibration(path: Path) -> RobotConfig:
            return msgspec.structs.replace(config, camera=msgspec.structs.replace(config.camera, calibration=str(path)))

        detectors = {"as detected": make_detector(with_calibration(lens_path)),
                     "inset undone": make_detector(with_calibration(undone_path))}
    pose = tuple(args.pose)
    errors, filters = at_pose(renderer, detectors, config, pose, args.frames)
    print(f"at ({pose[0]}, {pose[1]}, {pose[2]}), {args.frames} frames, per marker: mean range and bearing error")
    for (way, marker), rows in sorted(errors.items()):
        e = np.array(rows)
        print(f"  {way:13s} marker {marker:2d}: range {e[:, 0].mean() * 100:+.2f} cm (sd {e[:, 0].std() * 100:.2f}), "
              f"bearing {math.degrees(e[:, 1].mean()):+.3f} deg")
    for way, ekf in filters.items():
        position, heading = pose_error(ekf, pose)
        reference = "   (reference: the lens calibration's share, 0 in the ideal profile)"
        reference = reference if way == "true corners" else ""
        print(f"  {way:13s} fused: {position * 100:.2f} cm {math.degrees(heading):.2f} deg{reference}")
    if args.poses <= 0:
        return
    rng = np.random.default_rng(11)
    fused: dict[str, list[float]] = {way: [] for way in detectors}
    ranges: dict[str, list[float]] = {way: [] for way in detectors}
    insets: list[tuple[int, float, bool, float]] = []  # (window, incidence deg, edge longer than the mean, inset)
    done = 0
    while done < args.poses:
        place = (rng.uniform(-1.4, 1.4), rng.uniform(-1.4, 1.4), rng.uniform(-math.pi, math.pi))
        if len([v for v in renderer.render(*place)[1] if v.range < 2.5]) < 2:
            continue
        done += 1
        errors, filters = at_pose(renderer, detectors, config, place, 10)
        image, visible = renderer.render(*place)
        truth = {v.id: v for v in visible}
        for lm in detectors["as detected"].detect(image):
            if lm.id in truth:
                corners = np.array(lm.corners).reshape(4, 2)
                inset, lengths = edge_insets(corners, truth[lm.id].corners)
                insets += [(refinement_window(corners), math.degrees(truth[lm.id].incidence), bool(n > lengths.mean()),
                            float(d)) for d, n in zip(inset, lengths, strict=True)]
        for way in detectors:
            fused[way].append(pose_error(filters[way], place)[0] * 100)
            ranges[way] += [e for (w, _), rows in errors.items() if w == way for e, _ in rows]
    print(f"{args.poses} random poses with two or more markers within 2.5 m, 10 frames each:")
    for way in detectors:
        p, r = np.array(fused[way]), np.array(ranges[way]) * 100
        print(f"  {way:13s} fused position p50 {np.median(p):.2f} cm  p90 {np.percentile(p, 90):.2f} cm  "
              f"max {p.max():.2f} cm; range error of {len(r)} sightings mean {r.mean():+.2f} cm sd {r.std():.2f} cm")
    table = np.array(insets)
    print("  edges as detected, px inside the square (mean): window, seen from square on, short/long edges")
    for window in (1, 2, 3):
        for low, high in ((0, 50), (50, 90)):
            rows = table[(table[:, 0] == window) & (table[:, 1] >= low) & (table[:, 1] < high)]
            if len(rows):
                short, long = rows[rows[:, 2] == 0, 3], rows[rows[:, 2] == 1, 3]
                print(f"    window {window} px, {low:2d}-{high} deg: {len(rows):4d} edges, {rows[:, 3].mean():.3f} px; "
                      f"short edges {short.mean() if len(short) else math.nan:.3f}, "
                      f"long {long.mean() if len(long) else math.nan:.3f}")


if __name__ == "__main__":
    main()
