"""The simulated camera's render time on the lab world, with its obstacles and without them.

    .venv/bin/python bench/camera_render.py [--frames 400]

Renders ``--frames`` 640x480 frames of the lab world (`sim/camera.py`, one OpenCV thread) from
random poses (seeded) in the room's free space, twice: the world as it is (its walls, partition,
crate and bench drawn, and hiding the markers behind them), and the same world with its
obstacles taken out (the reference, measured in the same run: what the renderer cost before it
drew obstacles). Prints mean, p99 and max per frame, next to the camera's frame period
(``camera.fps``): the budget a render must stay well inside.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import cv2
import msgspec
import numpy as np

from icefloe import config as config_mod
from icefloe.sim.camera import CameraRenderer, true_intrinsics
from icefloe.vision.geometry import Mount
from icefloe.worldmap import load_world


def times_ms(renderer: CameraRenderer, poses: list[tuple[float, float, float]]) -> tuple[list[float], int]:
    """Per-frame render time, ms, and how many markers the frames showed in all."""
    out, seen = [], 0
    for pose in poses:
        t = time.perf_counter()
        _, visible = renderer.render(*pose)
        out.append((time.perf_counter() - t) * 1e3)
        seen += len(visible)
    return out, seen


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=400, help="frames rendered per world")
    args = p.parse_args()
    cv2.setNumThreads(1)
    cfg = config_mod.load()
    world = load_world("lab")
    bare = msgspec.structs.replace(world, obstacles=())
    rng = np.random.default_rng(5)
    poses: list[tuple[float, float, float]] = []
    while len(poses) < args.frames:  # where the robot can be: not inside an obstacle
        x, y = rng.uniform(-1.8, 1.8, 2)
        if world.clearance(x, y) > 0.1:
            poses.append((float(x), float(y), float(rng.uniform(-math.pi, math.pi))))
    budget = 1e3 / cfg.camera.fps
    print(f"{args.frames} frames {cfg.camera.width}x{cfg.camera.height} of the lab world, one OpenCV thread; "
          f"frame period at camera.fps = {cfg.camera.fps:g}: {budget:.1f} ms")
    rows = {}
    for name, w in (("without obstacles (reference)", bare), ("with its 7 obstacles", world)):
        renderer = CameraRenderer(w, true_intrinsics(cfg), Mount.from_config(cfg.camera), cfg.camera.dictionary,
                                  seed=3)
        renderer.render(0.0, 0.0, 0.0)  # textures made once, as in the camera service
        ms, seen = times_ms(renderer, poses)
        rows[name] = ms
        ordered = sorted(ms)
        print(f"  {name:<30} mean {statistics.mean(ms):5.2f} ms  p99 {ordered[int(0.99 * len(ms))]:5.2f} ms  "
              f"max {ordered[-1]:5.2f} ms  ({seen / len(poses):.2f} markers in view per frame)")
    without, with_ = (statistics.mean(v) for v in rows.values())
    print(f"  obstacles cost {with_ - without:+.2f} ms a frame ({with_ / without:.2f}x); "
          f"p99 with them is {100 * sorted(rows['with its 7 obstacles'])[int(0.99 * args.frames)] / budget:.0f} % "
          "of the frame period")


if __name__ == "__main__":
    main()
