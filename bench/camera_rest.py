"""How much the camera's picture changes standing, turning and driving: what ``camera.still_threshold`` is set from.

    .venv/bin/python bench/camera_rest.py [--frames 60] [--poses 8]

The camera rests (searches ``camera.rest_detection_rate_hz`` frames a second) while its
picture's thumbnail stays within ``camera.still_threshold`` of the still spell's first one
(`services/camera/rest.py`). For seeded poses in the lab, in the ideal and the realistic profiles
(``[sim] profile``: flicker, noise, exposure, JPEG), the simulated camera renders ``--frames`` frames
at ``camera.fps`` of a robot standing still, turning at 0.5 rad/s and driving at 0.15 m/s (and 0.05),
and this prints the change of each frame from the first (`rest.change`): the largest for a still
robot must stay below the threshold, the moving robot's must cross it within a few frames. Also the
thumbnail's CPU time per frame next to detection's on the same frames.
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from common import robot_config

from icefloe import config as config_mod
from icefloe.services.camera.detection import make_detector
from icefloe.services.camera.rest import change, thumbnail
from icefloe.sim.camera import CameraRenderer

MOTIONS = {"standing": (0.0, 0.0), "turning 0.5 rad/s": (0.0, 0.5), "driving 0.15 m/s": (0.15, 0.0),
           "driving 0.05 m/s": (0.05, 0.0)}
"""Name -> (v m/s, w rad/s)."""


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=30, help="frames rendered of each motion from each pose")
    p.add_argument("--poses", type=int, default=6, help="seeded start poses in the lab")
    args = p.parse_args()
    load = os.getloadavg()[0]
    folder = Path(tempfile.mkdtemp())
    rng = np.random.default_rng(7)
    starts = [(rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(-math.pi, math.pi))
              for _ in range(args.poses)]
    for profile in ("ideal", "realistic"):
        cfg = config_mod.load(str(robot_config(folder, f"rest{profile}", f'[sim]\nprofile = "{profile}"\n')))
        threshold, dt = cfg.camera.still_threshold, 1.0 / cfg.camera.fps
        renderer = CameraRenderer.of_robot(cfg, seed=3)
        detector = make_detector(cfg)
        thumb_s = detect_s = 0.0
        counted = 0
        print(f"{profile} profile, {args.poses} poses x {args.frames} frames at {cfg.camera.fps:g} fps; "
              f"camera.still_threshold {threshold:g}")
        for name, (v, w) in MOTIONS.items():
            largest, crossed = [], []
            for x, y, theta in starts:
                first = None
                changes = []
                for i in range(args.frames):
                    t = i * dt
                    heading = theta + w * t
                    image, _ = renderer.render(x + v * t * math.cos(theta), y + v * t * math.sin(theta), heading,
                                               turn_rate=w)
                    start = time.process_time()
                    thumb = thumbnail(image)
                    thumb_s += time.process_time() - start
                    if name == "standing":
                        start = time.process_time()
                        detector.detect(image)
                        detect_s += time.process_time() - start
                        counted += 1
                    if first is None:
                        first = thumb
                        continue
                    changes.append(change(thumb, first))
                largest.append(max(changes))
                over = [i + 1 for i, c in enumerate(changes) if c > threshold]
                crossed.append(over[0] if over else None)
            late = [c for c in crossed if c is not None]
            print(f"  {name:<18} largest change from the first frame {min(largest):.3f}-{max(largest):.3f}; "
                  f"over the threshold after {min(late) if late else '-'}-{max(late) if late else '-'} frames "
                  f"({sum(c is None for c in crossed)} of {len(crossed)} never)")
        frames = counted + 0
        print(f"  CPU per frame: thumbnail {1e3 * thumb_s / (frames * len(MOTIONS)):.3f} ms, "
              f"detection {1e3 * detect_s / frames:.2f} ms")
    print(f"load average {load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
