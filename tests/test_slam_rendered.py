"""The project's SLAM on rendered frames in the realistic profile: sim + hwbridge + odometry + camera + slam
as real processes, the camera calibrated first as `icefloe calibrate` would (offline on the calibration
world's boards, `sim/camera_calibration.py`), nothing played: the camera service renders the lab through
the realistic lens and picture and detects its markers; SLAM maps them. Scored against the world file
with `icefloe score`'s maths. About 60-90 s (a 45 s tour).

    .venv/bin/pytest -s tests/test_slam_rendered.py     # prints the figures
"""

from __future__ import annotations

import asyncio
import math
import time

import pytest
from conftest import wait_for
from test_localizer_sim import check_exits, collect

from icefloe import config as config_mod
from icefloe.angles import wrap_angle
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.score.maths import score_map
from icefloe.sim.camera_calibration import calibrate_camera
from icefloe.worldmap import load_world

pytestmark = pytest.mark.slow

TRUE = {mk.id: (mk.x, mk.y) for mk in load_world("lab").markers}
SQUARE = [(1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.0, 0.0)]
"""Corners driven to in turn, counter-clockwise, m (bench/sim_profiles.py's tour)."""
TOUR_S = 45.0


async def drive(node, truth: list[m.Truth]) -> float:
    """Round `SQUARE` for `TOUR_S`, steering on the true pose (the same path whatever the wheels); m driven."""
    twist = node.publisher(keys.TWIST)
    start, corner, driven, last = time.monotonic(), 0, 0.0, truth[-1]
    while time.monotonic() - start < TOUR_S:
        t = truth[-1]
        driven += math.hypot(t.x - last.x, t.y - last.y)
        last = t
        gx, gy = SQUARE[corner % len(SQUARE)]
        if math.hypot(gx - t.x, gy - t.y) < 0.05:
            corner += 1
            continue
        err = wrap_angle(math.atan2(gy - t.y, gx - t.x) - t.theta)
        twist.put(m.Twist(v=0.0, w=max(-1.0, min(1.0, 3.0 * err))) if abs(err) > 0.15 else m.Twist(v=0.2, w=2 * err))
        await asyncio.sleep(0.05)
    node.publisher(keys.STOP).put(m.Stop())
    return driven


@pytest.mark.timeout(400)
async def test_slam_maps_the_lab_from_rendered_frames_in_the_realistic_profile(make_robot, tmp_path) -> None:
    """Measured (2026-12-07, seed 4, load about 10, 58 s): a 6.9 m tour, 10 of 12 markers, RMSE 2.94 cm
    after alignment (worst 6.5 cm); bench/sim_profiles.py's 120 s tour: 3.64 cm (ideal profile: 1.33 cm).
    The bound is the issue's: at least 8 markers within 5 cm (the goal beyond, 2 cm, is not reached)."""
    profile = '[sim]\nprofile = "realistic"\nseed = 4\n'
    calibrated = calibrate_camera(config_mod.parse({"sim": {"profile": "realistic", "seed": 4}}),
                                  tmp_path / "camera.yaml", seed=4)
    robot = make_robot(profile + f'[camera]\ncalibration = "{tmp_path / "camera.yaml"}"\n')
    procs = [robot.start(s) for s in ("sim", "hwbridge", "odometry", "camera", "slam")]
    truth: list[m.Truth] = []
    maps: list[m.LandmarkMap] = []
    async with robot.node("tester") as node:
        tasks = [asyncio.create_task(collect(node.subscribe(topic, latest=False, maxsize=1024), into))
                 for topic, into in ((keys.TRUTH, truth), (keys.SLAM_MAP, maps))]
        await wait_for(lambda: truth and maps, timeout=90)
        driven = await drive(node, truth)
        stamp = truth[-1].stamp
        await wait_for(lambda: maps[-1].stamp >= stamp, timeout=30)
        for task in tasks:
            task.cancel()
    check_exits(procs)
    score = score_map({p.id: (p.x, p.y) for p in maps[-1].landmarks}, TRUE)
    print(f"\ncamera calibrated: {calibrated}\ntour {driven:.1f} m; SLAM map {len(score.errors)} of {len(TRUE)} "
          f"markers, RMSE {score.rmse * 100:.2f} cm after alignment (worst {max(score.errors.values()) * 100:.2f} cm)")
    assert len(score.errors) >= 8
    assert score.rmse < 0.05
