"""The simulated camera's render time on the track world, with its road and without it.

    .venv/bin/python bench/track_render.py [--frames 400]

Renders ``--frames`` 640x480 frames of ``deploy/worlds/track.toml`` (`sim/camera.py`, one OpenCV
thread) from poses along the road as a lap drives it (the centerline's points, seeded jitter of a
few cm and degrees), twice: the world with its track (the floor's texture warped below the
horizon, the stop sign, frames in colour) and the same world with the track taken out (the
reference, measured in the same run: the grey frame a world without a road renders). Prints mean,
p99 and max per frame next to the camera's frame period (``camera.fps``), and what making the
floor's texture costs (once, when the camera starts).
"""

from __future__ import annotations

import argparse
import statistics
import time

import cv2
import msgspec
import numpy as np

from icefloe import config as config_mod
from icefloe.sim.camera import CameraRenderer, true_intrinsics
from icefloe.sim.floor import floor_texture
from icefloe.vision.geometry import Mount
from icefloe.worldmap import load_world


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=400, help="frames rendered per world")
    args = p.parse_args()
    cv2.setNumThreads(1)
    cfg = config_mod.load()
    world = load_world("track")
    assert world.track is not None
    line = world.track.centerline()
    heading = np.arctan2(*np.gradient(line, axis=0)[:, ::-1].T)
    rng = np.random.default_rng(5)
    at = rng.integers(0, len(line) - 1, args.frames)
    poses = [(float(line[i, 0] + rng.normal(0, 0.03)), float(line[i, 1] + rng.normal(0, 0.03)),
              float(heading[i] + rng.normal(0, 0.1))) for i in at]
    budget = 1e3 / cfg.camera.fps
    t = time.perf_counter()
    floor_texture(world.track)
    texture_ms = (time.perf_counter() - t) * 1e3
    print(f"{args.frames} frames {cfg.camera.width}x{cfg.camera.height} along the track world's road, one OpenCV "
          f"thread; frame period at camera.fps = {cfg.camera.fps:g}: {budget:.1f} ms")
    rows = {}
    for name, w in (("without the track (reference)", msgspec.structs.replace(world, track=None)),
                    ("with its track", world)):
        renderer = CameraRenderer(w, true_intrinsics(cfg), Mount.from_config(cfg.camera), cfg.camera.dictionary,
                                  seed=3)
        renderer.render(*poses[0])  # textures made once, as in the camera service
        ms = []
        for pose in poses:
            t = time.perf_counter()
            renderer.render(*pose)
            ms.append((time.perf_counter() - t) * 1e3)
        rows[name] = sorted(ms)
        print(f"  {name:<30} mean {statistics.mean(ms):5.2f} ms  p99 {rows[name][int(0.99 * len(ms))]:5.2f} ms  "
              f"max {rows[name][-1]:5.2f} ms")
    without, with_ = (statistics.mean(v) for v in rows.values())
    print(f"  the track costs {with_ - without:+.2f} ms a frame ({with_ / without:.2f}x); p99 with it is "
          f"{100 * rows['with its track'][int(0.99 * args.frames)] / budget:.0f} % of the frame period; "
          f"its floor texture took {texture_ms:.0f} ms to make (once)")


if __name__ == "__main__":
    main()
