"""SLAM on the simulated lab after a tour: map RMSE and final pose error, next to the map-based
localizer and odometry alone on the same run, and the CPU of each reference service.

    .venv/bin/python bench/slam.py [--seconds 120] [--seed 4]

Real processes on a router of their own: sim (slip 0.05, encoder noise 0.01), hwbridge,
odometry, localizer, slam and mapper (known pose: sim/truth). This script drives round a 1 m
square in the lab's clear space with ``cmd/twist``, steering on the true pose (so every run drives
the same tour), and plays the camera: every third ``sim/truth`` sample (~17 Hz) becomes the
sightings the camera would make (`icefloe.testing.TruthCamera`: field of view, range, seeded noise) on
``camera/landmarks``. At the end:

* the map of ``slam/map`` and of ``map/landmarks`` scored with `icefloe score`'s maths
  (rigid Umeyama alignment to the world's markers, RMSE; the map maker's also unaligned);
* the final pose error of ``slam/pose`` (moved by the map's alignment: SLAM's frame is its own),
  ``loc/pose`` (the map-based localizer, world frame) and ``odom/pose`` (odometry alone);
* each service's user + system CPU over the tour, from /proc/<pid>/stat, % of one core.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import ROOT, cpu_seconds_with_children, robot_config

from icefloe.angles import wrap_angle
from icefloe.config import load
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.score.maths import score_map
from icefloe.testing import TruthCamera, play_camera, steer_round
from icefloe.worldmap import load_world

SERVICES = ("sim", "hwbridge", "odometry", "localizer", "slam", "mapper")
SQUARE = [(1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.0, 0.0)]
"""Corners driven to in turn, counter-clockwise, m (inside the lab's clear square)."""


async def tour(config_path: Path, seconds: float, seed: int, procs: dict[str, subprocess.Popen]) -> dict:
    config = load(config_path)
    latest: dict[str, object] = {}
    async with Node("bench", config) as node:
        camera = TruthCamera(config, random.Random(seed))
        twist = node.publisher(keys.TWIST)

        async def keep(topic: keys.Topic) -> None:
            async for msg in node.subscribe(topic):
                latest[topic.name] = msg

        tasks = [asyncio.create_task(play_camera(node, camera, on_truth=lambda t, _: latest.update(truth=t)))]
        tasks += [asyncio.create_task(keep(t)) for t in (
            keys.ODOM_POSE, keys.LOC_POSE, keys.SLAM_POSE, keys.SLAM_MAP, keys.MAP_LANDMARKS)]
        t0 = time.monotonic()
        while not all(k in latest for k in ("truth", "odom/pose", "loc/pose")):
            if time.monotonic() - t0 > 120:
                raise SystemExit(f"the services did not start within 120 s: have {sorted(latest)}")
            await asyncio.sleep(0.2)
        cpu0 = {name: cpu_seconds_with_children(p.pid) for name, p in procs.items()}
        start = time.monotonic()
        corner, driven, last = 0, 0.0, latest["truth"]
        while time.monotonic() - start < seconds:  # steer on the true pose: every run drives the same square
            t = latest["truth"]
            driven += math.hypot(t.x - last.x, t.y - last.y)
            last = t
            corner, step = steer_round(SQUARE, corner, t)
            if step is None:
                continue
            twist.put(step)
            await asyncio.sleep(0.05)
        latest["driven"] = driven
        node.publisher(keys.STOP).put(m.Stop())
        wall = time.monotonic() - start
        cpu = {name: (cpu_seconds_with_children(p.pid) - cpu0[name]) / wall for name, p in procs.items()}
        await asyncio.sleep(2.0)  # the wheels at rest, the last estimates out
        for task in tasks:
            task.cancel()
    latest["cpu"] = cpu
    latest["wall"] = wall
    return latest


def report(got: dict) -> None:
    world = {mk.id: (mk.x, mk.y) for mk in load_world("lab").markers}
    truth: m.Truth = got["truth"]
    slam = score_map({p.id: (p.x, p.y) for p in got["slam/map"].landmarks}, world)
    made = score_map({p.id: (p.x, p.y) for p in got["map/landmarks"].landmarks}, world)
    pose = got["slam/pose"]
    (px, py), = slam.alignment.apply(np.array([[pose.x, pose.y]]))
    rows = [("SLAM (slam/pose, aligned by its map)", px, py, pose.theta + slam.alignment.rotation),
            ("map-based localizer (loc/pose)", got["loc/pose"].x, got["loc/pose"].y, got["loc/pose"].theta),
            ("odometry alone (odom/pose)", got["odom/pose"].x, got["odom/pose"].y, got["odom/pose"].theta)]
    print(f"tour: {got['wall']:.0f} s, {got['driven']:.1f} m driven (truth), {truth.collisions} collisions")
    print(f"SLAM map: {len(slam.errors)} of {len(world)} markers, RMSE after alignment {slam.rmse * 100:.2f} cm "
          f"(worst {max(slam.errors.values()) * 100:.2f} cm)")
    print(f"map maker (known pose = sim/truth): {len(made.errors)} markers, RMSE {made.rmse * 100:.2f} cm "
          f"after alignment, {made.rmse_raw * 100:.2f} cm as made")
    print("final pose error:")
    for name, x, y, th in rows:
        print(f"  {name:38s} {math.hypot(x - truth.x, y - truth.y) * 100:6.2f} cm "
              f"{math.degrees(abs(wrap_angle(th - truth.theta))):5.2f} deg")
    print("CPU over the tour, % of one core:")
    for name, share in got["cpu"].items():
        print(f"  {name:10s} {share * 100:5.1f} %")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=120.0, help="how long the tour drives, s")
    parser.add_argument("--seed", type=int, default=4, help="seed of the simulator and the camera's noise")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "run").mkdir(mode=0o700)
        path = robot_config(folder, "slambench", f"[sim]\nseed = {args.seed}\nslip = 0.05\nencoder_noise = 0.01\n")
        base = [sys.executable, "-m"]
        cfg = ["--config", str(path)]
        router = subprocess.Popen([*base, "icefloe.router", *cfg], cwd=ROOT, stdin=subprocess.DEVNULL)
        procs: dict[str, subprocess.Popen] = {}
        try:
            time.sleep(1.0)
            for s in SERVICES:
                procs[s] = subprocess.Popen([*base, f"icefloe.services.{s}", *cfg], cwd=ROOT, stdin=subprocess.DEVNULL,
                                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            report(asyncio.run(tour(path, args.seconds, args.seed, procs)))
        finally:
            for p in [*reversed(procs.values()), router]:
                p.terminate()
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()


if __name__ == "__main__":
    main()
