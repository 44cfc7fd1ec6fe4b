"""The reference services live on rendered frames, in both profiles of the simulator, side by side: the
map's RMSE and markers found, each pose's error against the truth (p50, p95, final), and the follower's
cross-track error driving a planned path on the localizer's pose.

    .venv/bin/python bench/sim_profiles.py [--seconds 120] [--seed 4] [--profiles ideal,realistic]

Real processes on a router of their own, one profile after the other (docs/sim.md): sim, hwbridge,
odometry, camera (rendering the lab from ``sim/truth`` and detecting its markers), localizer, slam and
mapper (known pose: ``sim/truth``). The tour is bench/slam.py's: a 1 m square in the lab's clear space,
steered on the true pose with ``cmd/twist`` so that both profiles drive the same path.

Before each run the camera is calibrated as `icefloe calibrate` would do it, offline on frames the
simulated camera renders of the calibration world's boards through the profile's lens and picture
(`sim/camera_calibration.py`): the lens (the ideal profile's is the one the camera believes: kept) and the
marker detector's corner inset. The capture latency is not measured (it needs the robot's own turn,
`calibrate --drive`): in the realistic profile the frames' stamps stay late by it, as on a robot
calibrated without ``--drive``.

After the tour, the planning services start as processes too (grid, planner, follower; docs/planning.md):
the bench asks ``nav/plan`` for a path from the localizer's pose, where the tour left the robot, to a
fixed goal across the lab (the far corner, round the crate: tests/test_planning_sim.py's), publishes it
on ``nav/path``, and the follower drives it steering on ``loc/pose`` (its default, as on a robot).
Measured on ``sim/truth``: the cross-track error to the planned path (p50, p95, max) while following,
whether it arrived and how far from the goal, and the time.

The reference line is the ideal profile.
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import ROOT, robot_config

from icefloe import config as config_mod
from icefloe.angles import wrap_angle
from icefloe.config import load
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.score.maths import score_map
from icefloe.services.follower.pursuit import project
from icefloe.sim.camera_calibration import calibrate_camera
from icefloe.testing import steer_round
from icefloe.vision.geometry import CameraCalibration, load_calibration, load_extras, save_calibration
from icefloe.worldmap import load_world

SERVICES = ("sim", "hwbridge", "odometry", "camera", "localizer", "slam", "mapper")
PLANNING = ("grid", "planner", "follower")
"""Started after the tour, so that the tour's figures are those of the stack without them."""
SQUARE = [(1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.0, 0.0)]
"""Corners driven to in turn, counter-clockwise, m (bench/slam.py's)."""
GOAL = (-1.5, -1.5)
"""Where the followed path goes from where the tour left the robot (the same place in both profiles, the tour
being steered on the truth): the lab's far corner, round the crate (tests/test_planning_sim.py's goal)."""
ARRIVED = 0.05
"""The follower reached the goal if it says ``arrived`` with the truth within this of the goal, m (its
own tolerance is 3 cm on the localizer's pose, which is itself a few cm off)."""


def pose_error(pose, truth: m.Truth) -> tuple[float, float]:
    return math.hypot(pose.x - truth.x, pose.y - truth.y), abs(wrap_angle(pose.theta - truth.theta))


async def tour(config_path: Path, seconds: float) -> dict:
    config = load(config_path)
    latest: dict[str, object] = {}
    samples: list[tuple[m.Truth, object, object, object]] = []
    async with Node("bench", config) as node:
        twist = node.publisher(keys.TWIST)

        async def keep(topic: keys.Topic) -> None:
            async for msg in node.subscribe(topic):
                latest[topic.name] = msg

        tasks = [asyncio.create_task(keep(t)) for t in (
            keys.TRUTH, keys.ODOM_POSE, keys.LOC_POSE, keys.SLAM_POSE, keys.SLAM_MAP, keys.MAP_LANDMARKS,
            keys.LANDMARKS)]
        t0 = time.monotonic()
        while not all(k in latest for k in ("sim/truth", "odom/pose", "loc/pose", "camera/landmarks")):
            if time.monotonic() - t0 > 120:
                raise SystemExit(f"the services did not start within 120 s: have {sorted(latest)}")
            await asyncio.sleep(0.2)
        start = time.monotonic()
        corner, driven, last = 0, 0.0, latest["sim/truth"]
        while time.monotonic() - start < seconds:  # steer on the true pose: every run drives the same square
            t = latest["sim/truth"]
            driven += math.hypot(t.x - last.x, t.y - last.y)
            last = t
            samples.append((t, latest["odom/pose"], latest["loc/pose"], latest.get("slam/pose")))
            corner, step = steer_round(SQUARE, corner, t)
            if step is None:
                continue
            twist.put(step)
            await asyncio.sleep(0.05)
        node.publisher(keys.STOP).put(m.Stop())
        await asyncio.sleep(2.0)  # the wheels at rest, the last estimates out
        for task in tasks:
            task.cancel()
    latest["driven"] = driven
    latest["samples"] = samples
    return latest


def distance_to_path(path: list[m.Waypoint], x: float, y: float) -> float:
    return min(project((a.x, a.y), (b.x, b.y), (x, y))[1] for a, b in itertools.pairwise(path))


async def follow(config_path: Path, limit: float = 180.0) -> dict:
    """A plan from the localizer's pose to `GOAL`, driven by the follower; the truth meanwhile."""
    config = load(config_path)
    truth: list[m.Truth] = []
    statuses: list[m.FollowStatus] = []
    async with Node("bench", config) as node:
        async def watch(topic: keys.Topic, into: list) -> None:
            async for msg in node.subscribe(topic, latest=False):
                into.append(msg)

        tasks = [asyncio.create_task(watch(keys.TRUTH, truth)), asyncio.create_task(watch(keys.NAV_STATUS, statuses))]
        loc = node.latest(keys.LOC_POSE)
        deadline = time.monotonic() + 120
        while True:  # the planner and the follower start slowly on a loaded machine
            pose = loc.get()
            try:
                if pose is None or not statuses:
                    raise TimeoutError("not up yet")
                plan = await node.query(keys.PLAN, m.PlanRequest(start_x=pose.x, start_y=pose.y, goal_x=GOAL[0],
                                                                  goal_y=GOAL[1]), timeout=10)
                break
            except Exception:
                if time.monotonic() > deadline:
                    raise SystemExit(f"no plan within 120 s (pose {pose}, follower status {statuses[-1:]})") from None
                await asyncio.sleep(0.5)
        if not plan.ok:
            raise SystemExit(f"no plan from {pose} to {GOAL}: {plan.reason}")
        start, t0 = len(truth), time.monotonic()
        path = node.command(m.NavPath, points=plan.path)
        node.publisher(keys.NAV_PATH).put(path)
        while time.monotonic() - t0 < limit:  # until the follower says it is done with this path
            if statuses[-1].seq == path.seq and statuses[-1].state in ("arrived", "stopped"):
                break
            await asyncio.sleep(0.05)
        seconds = time.monotonic() - t0
        await asyncio.sleep(1.0)  # the wheels at rest
        for task in tasks:
            task.cancel()
    return {"plan": plan, "truth": truth[start:], "status": statuses[-1], "seconds": seconds}


def follow_figures(got: dict) -> dict[str, str]:
    plan, truth, status = got["plan"], got["truth"], got["status"]
    errs = np.array([distance_to_path(plan.path, t.x, t.y) for t in truth]) if truth else np.array([np.nan])
    end = truth[-1] if truth else None
    off = math.dist((end.x, end.y), GOAL) if end else math.nan
    reached = status.state == "arrived" and off < ARRIVED
    return {
        "plan to (-1.5, -1.5): points, length": f"{len(plan.path)}, {plan.length:.2f} m",
        "follower cross-track p50/p95/max cm": f"{np.percentile(errs, 50) * 100:.1f} / "
                                               f"{np.percentile(errs, 95) * 100:.1f} / {errs.max() * 100:.1f}",
        "follower: goal reached, off (truth)": f"{'yes' if reached else 'no'} ({status.state}), {off * 100:.1f} cm",
        "follower: time, collisions": f"{got['seconds']:.1f} s, {end.collisions if end else '-'}",
    }


def figures(got: dict) -> dict[str, str]:
    """Each row of the side-by-side table, as text."""
    world = {mk.id: (mk.x, mk.y) for mk in load_world("lab").markers}
    rows: dict[str, str] = {}
    slam = score_map({p.id: (p.x, p.y) for p in got["slam/map"].landmarks}, world) if "slam/map" in got else None
    made = score_map({p.id: (p.x, p.y) for p in got["map/landmarks"].landmarks}, world) \
        if "map/landmarks" in got else None
    rows["SLAM map: markers, RMSE aligned"] = \
        f"{len(slam.errors)}/{len(world)}, {slam.rmse * 100:.2f} cm" if slam else "no map"
    rows["mapper (known pose) markers, RMSE"] = \
        f"{len(made.errors)}/{len(world)}, {made.rmse * 100:.2f} cm" if made else "no map"

    def moved(pose):  # SLAM's frame is its own: into the world's by its map's alignment
        (x, y), = slam.alignment.apply(np.array([[pose.x, pose.y]]))
        return m.Pose(stamp=pose.stamp, x=float(x), y=float(y), theta=pose.theta + slam.alignment.rotation)

    samples = got["samples"]
    final = samples[-1][0] if not got.get("sim/truth") else got["sim/truth"]
    for name, index, key in (("odometry (odom/pose)", 1, "odom/pose"), ("localizer (loc/pose)", 2, "loc/pose"),
                             ("SLAM (slam/pose, aligned)", 3, "slam/pose")):
        poses = [(s[0], s[index]) for s in samples if s[index] is not None]
        if key == "slam/pose":
            if slam is None or not poses:
                rows[f"{name} p50/p95/final"] = "none"
                continue
            poses = [(t, moved(p)) for t, p in poses]
            last = moved(got[key])
        else:
            last = got[key]
        errs = np.array([pose_error(p, t)[0] for t, p in poses])
        rows[f"{name} p50/p95/final cm"] = (f"{np.percentile(errs, 50) * 100:.1f} / {np.percentile(errs, 95) * 100:.1f}"
                                            f" / {pose_error(last, final)[0] * 100:.1f}")
    rows["driven (truth), collisions"] = f"{got['driven']:.1f} m, {final.collisions}"
    return rows


def run(profile: str, seconds: float, seed: int, folder: Path, latency_s: float) -> tuple[str, dict[str, str]]:
    camera_file = folder / f"{profile}.camera.yaml"
    found = calibrate_camera(config_mod.parse({"sim": {"profile": profile, "seed": seed}}), camera_file, seed)
    if latency_s and profile != "ideal":  # as if `calibrate --drive` had measured it
        extras = load_extras(camera_file)
        save_calibration(camera_file, load_calibration(camera_file, 640, 480), None,
                         CameraCalibration(extras.inset, latency_s))
        found += f"; capture latency {latency_s * 1000:.0f} ms (given)"
    path = robot_config(folder, f"bench{profile}", f'[sim]\nprofile = "{profile}"\nseed = {seed}\n'
                        f'[camera]\ncalibration = "{camera_file}"\n')
    base, cfg = [sys.executable, "-m"], ["--config", str(path)]
    router = subprocess.Popen([*base, "icefloe.router", *cfg], cwd=ROOT, stdin=subprocess.DEVNULL)
    procs: list[subprocess.Popen] = []
    try:
        time.sleep(1.0)
        for s in SERVICES:
            procs.append(subprocess.Popen([*base, f"icefloe.services.{s}", *cfg], cwd=ROOT, stdin=subprocess.DEVNULL,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        rows = figures(asyncio.run(tour(path, seconds)))
        for s in PLANNING:
            procs.append(subprocess.Popen([*base, f"icefloe.services.{s}", *cfg], cwd=ROOT, stdin=subprocess.DEVNULL,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        rows.update(follow_figures(asyncio.run(follow(path))))
        return found, rows
    finally:
        for p in [*reversed(procs), router]:
            p.terminate()
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=120.0, help="how long each tour drives, s")
    parser.add_argument("--seed", type=int, default=4, help="seed of the simulator's effects")
    parser.add_argument("--profiles", default="ideal,realistic", help="comma-separated (default both)")
    parser.add_argument("--latency", type=float, default=0.0, metavar="S",
                        help="write this capture latency into the realistic camera's calibration, as if "
                             "`icefloe calibrate --drive` had measured it (default: none, as without --drive)")
    args = parser.parse_args()
    profiles = args.profiles.split(",")
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "run").mkdir(mode=0o700)  # the robots' run dir (bench/common.py), one after the other
        for profile in profiles:
            found, rows = run(profile, args.seconds, args.seed, Path(tmp), args.latency)
            print(f"{profile}: calibrated {found}", flush=True)
            results[profile] = rows
    print(f"\n{args.seconds:.0f} s tour, seed {args.seed}; the reference is the first column")
    names = list(next(iter(results.values())))
    print(f"{'':38s}" + "".join(f"{p:>24s}" for p in profiles))
    for name in names:
        print(f"{name:38s}" + "".join(f"{results[p].get(name, '-'):>24s}" for p in profiles))


if __name__ == "__main__":
    main()
