"""Camera figures: renderer speed, detection cost next to bare OpenCV, capture -> landmarks latency.

    .venv/bin/python bench/camera_detection.py [--frames 300] [--seconds 10]

1. Renders ``--frames`` 640x480 frames of the lab world from random poses (seeded).
2. On one OpenCV thread, times on the same frames: bare `ArucoDetector.detectMarkers`
   with OpenCV's default parameters, bare `detectMarkers` with the service's
   parameters (sub-pixel corners), and the service's whole per-frame work
   (frame check, detection, solvePnP per marker, Landmark messages, MessagePack).
3. Runs the camera service as a process on a folder of those frames (replay at
   30 fps: the capture time is stamped when a frame is read) and measures, on the
   bus, capture -> `camera/landmarks` received.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from common import robot_config

from icefloe import config as config_mod
from icefloe.runtime import Node
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m
from icefloe.services.camera.detection import make_detector
from icefloe.sim.camera import CameraRenderer
from icefloe.vision.geometry import Intrinsics, Mount
from icefloe.vision.sources import check_frame
from icefloe.worldmap import load_world

ROOT = Path(__file__).resolve().parent.parent


def per_frame_ms(fn, frames: list[np.ndarray]) -> list[float]:
    out = []
    for f in frames:
        t = time.perf_counter()
        fn(f)
        out.append((time.perf_counter() - t) * 1e3)
    return out


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


async def latency(config_path: Path, seconds: float) -> list[float]:
    cfg = config_mod.load(config_path)
    out: list[float] = []
    async with Node("bench", cfg) as node:
        sub = node.subscribe(keys.LANDMARKS, latest=False, maxsize=10000)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            msg = await asyncio.wait_for(sub.__anext__(), 30)
            out.append((time.time_ns() - msg.stamp) / 1e6)
    return out[5:]  # the first frames include start-up


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--seconds", type=float, default=10.0)
    args = p.parse_args()
    cv2.setNumThreads(1)
    cfg = config_mod.load()
    world = load_world(cfg.sim.world)
    renderer = CameraRenderer(world, Intrinsics.from_config(cfg.camera), Mount.from_config(cfg.camera),
                              cfg.camera.dictionary, seed=3)
    rng = np.random.default_rng(5)
    poses = [(rng.uniform(-1.2, 1.2), rng.uniform(-1.2, 1.2), rng.uniform(-math.pi, math.pi))
             for _ in range(args.frames)]
    t = time.perf_counter()
    frames = [renderer.render(*pose)[0] for pose in poses]
    render_ms = (time.perf_counter() - t) * 1e3 / len(frames)

    detector = make_detector(cfg)
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, cfg.camera.dictionary))
    bare_default = cv2.aruco.ArucoDetector(dictionary, cv2.aruco.DetectorParameters())
    bare_same = cv2.aruco.ArucoDetector(dictionary, detector._aruco.getDetectorParameters())
    gray = [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in frames]

    def service(frame: np.ndarray) -> bytes:
        found = detector.detect(check_frame(frame, cfg.camera.width, cfg.camera.height))
        return codec.encode(m.Landmarks(stamp=0, landmarks=found))

    rows = {
        "bare detectMarkers, default parameters (reference)": per_frame_ms(bare_default.detectMarkers, gray),
        "bare detectMarkers, the service's parameters (reference)": per_frame_ms(bare_same.detectMarkers, gray),
        "service per frame (BGR in, Landmarks encoded out)": per_frame_ms(service, frames),
    }
    print(f"{len(frames)} frames 640x480, one OpenCV thread; renderer {render_ms:.2f} ms/frame "
          f"({1e3 / render_ms:.0f} fps)")
    for name, ms in rows.items():
        print(f"  {name:<58} mean {statistics.mean(ms):6.2f} ms  p99 {pct(ms, 0.99):6.2f} ms  "
              f"= {1e3 / statistics.mean(ms):5.0f} fps")
    ratio = statistics.mean(rows["service per frame (BGR in, Landmarks encoded out)"]) / statistics.mean(
        rows["bare detectMarkers, the service's parameters (reference)"])
    print(f"  service / bare (same parameters): {ratio:.2f}x   (goals: >= 30 fps, <= 1.2x)")

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "frames"
        folder.mkdir()
        for i, f in enumerate(frames[:60]):
            cv2.imwrite(str(folder / f"{i:04d}.png"), f)
        config_path = robot_config(Path(tmp), "cambench", f'[camera]\nsource = "{folder}"\nfps = 30.0\n')
        py = [sys.executable, "-m"]
        procs = [subprocess.Popen([*py, "icefloe.router", "--config", str(config_path)],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
        time.sleep(1.0)
        procs.append(subprocess.Popen([*py, "icefloe.services.camera", "--config", str(config_path)],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        try:
            lat = asyncio.run(latency(config_path, args.seconds))
        finally:
            for proc in reversed(procs):
                proc.terminate()
                proc.wait()
    print(f"capture -> camera/landmarks received (replay at 30 fps, {len(lat)} frames): "
          f"p50 {pct(lat, 0.5):.1f} ms  p99 {pct(lat, 0.99):.1f} ms  max {max(lat):.1f} ms   (goal: p99 < 50 ms)")


if __name__ == "__main__":
    main()
