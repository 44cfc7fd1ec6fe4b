"""What the camera's detection costs at each resolution and rate, here and converted to a Pi 3B.

    .venv/bin/python bench/camera_cost.py [--frames 100]

The camera service's CPU is mostly ArUco detection (`Detector.detect`: OpenCV's C++, then
solvePnP per marker), run ``camera.detection_rate_hz`` times a second on frames of
``camera.width`` x ``camera.height``. For each resolution below, the simulated camera renders
``--frames`` frames of the lab world from the same seeded poses, through the same lens
(``camera.focal_px`` scaled with the width, as a camera that bins its sensor), and the service's
detector is timed on them in this process (CPU time, one OpenCV thread, as in the service).
The markers found per frame say what a smaller frame loses (the far markers first).

The reference, in the same run: the whole per-frame cost at 640x480, which is what
bench/stack_cpu.py's "camera" row is made of at ``camera.fps`` (15 by default). The figures are
converted to Raspberry Pi 3B cores with `common.PI3B_SLOWER` and its range (docs/deploy.md).
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import cv2
import numpy as np
from common import PI3B_RANGE, PI3B_SLOWER, robot_config

from icefloe import config as config_mod
from icefloe.services.camera.detection import make_detector
from icefloe.sim.camera import CameraRenderer
from icefloe.vision.geometry import Intrinsics, Mount
from icefloe.worldmap import load_world

SIZES = [(640, 480), (480, 360), (320, 240)]
RATES = [15.0, 10.0, 5.0]


def per_frame(size: tuple[int, int], frames: int, folder: Path) -> tuple[float, float]:
    """CPU ms per frame of the service's detector at ``size``, and the markers found per frame."""
    width, height = size
    base = config_mod.load(str(robot_config(folder, "camcost", "")))
    focal = base.camera.focal_px * width / 640
    path = robot_config(folder, f"camcost{width}",
                        f"[camera]\nwidth = {width}\nheight = {height}\nimage_width = {min(320, width)}\n"
                        f"image_height = {min(240, height)}\nfocal_px = {focal}\n")
    cfg = config_mod.load(str(path))
    renderer = CameraRenderer(load_world(cfg.sim.world), Intrinsics.from_config(cfg.camera),
                              Mount.from_config(cfg.camera), cfg.camera.dictionary, seed=3)
    rng = np.random.default_rng(5)
    poses = [(rng.uniform(-1.2, 1.2), rng.uniform(-1.2, 1.2), rng.uniform(-math.pi, math.pi)) for _ in range(frames)]
    images = [renderer.render(*pose)[0] for pose in poses]
    detector = make_detector(cfg)
    detector.detect(images[0])  # warm up
    found = 0
    start = time.process_time()
    for image in images:
        found += len(detector.detect(image))
    return 1e3 * (time.process_time() - start) / len(images), found / len(images)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=100, help="frames rendered and searched at each resolution")
    args = p.parse_args()
    cv2.setNumThreads(1)
    import os
    import tempfile

    load = os.getloadavg()[0]
    folder = Path(tempfile.mkdtemp())
    rows = [(size, *per_frame(size, args.frames, folder)) for size in SIZES]
    low, high = PI3B_RANGE
    print(f"camera detection, {args.frames} frames each, CPU time, one OpenCV thread; load average {load:.1f} "
          f"at the start, {os.getloadavg()[0]:.1f} at the end; a Pi 3B core {PI3B_SLOWER:g}x slower "
          f"({low:g}-{high:g}x)")
    print(f"  {'size':>9} {'ms/frame':>9} {'markers/frame':>14}   " +
          "   ".join(f"{rate:>4g} Hz: % here, Pi 3B cores" for rate in RATES))
    for (width, height), ms, found in rows:
        cells = []
        for rate in RATES:
            here = ms * rate / 10  # ms per frame x frames a second / 1000 ms x 100 %
            cells.append(f"{here:8.1f} %  {here / 100 * PI3B_SLOWER:4.2f} ({here / 100 * low:.2f}-"
                         f"{here / 100 * high:.2f})")
        print(f"  {width:>4}x{height:<4} {ms:9.2f} {found:14.2f}   " + "   ".join(cells))


if __name__ == "__main__":
    main()
