"""End to end with real processes: sim + hwbridge + odometry + slam + mapper, scored against the
simulator's truth with `icefloe score`'s maths; hostile sightings; a student's map maker in their place.

As in test_localizer_sim.py, the test plays the camera: each ``sim/truth`` sample becomes the
sightings the camera would make (`icefloe.testing.TruthCamera`, seeded noise) on ``camera/landmarks``. About 40 s
alone per test; more on a loaded machine (bounded waits).
"""

from __future__ import annotations

import asyncio
import math
import random
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import Proc, wait_for
from test_localizer_sim import check_exits, drive_legs

from icefloe.angles import wrap_angle
from icefloe.launcher import program_environment
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.score.maths import score_map
from icefloe.testing import TruthCamera, play_camera
from icefloe.worldmap import load_world

TRUE = {mk.id: (mk.x, mk.y) for mk in load_world("lab").markers}
TOUR = [(0.2, 0.0, 4.0), (0.0, 1.5, math.pi / 3)] * 4  # a 0.8 m square, about 23 s
SIM = "[sim]\nseed = 4\nslip = 0.05\nencoder_noise = 0.01\n"


async def tour(robot, node, services: tuple[str, ...], *, student: list | None = None) -> dict:
    """Start the services, play the camera while driving TOUR; the latest message on each key."""
    procs = [robot.start(s) for s in ("sim", "hwbridge", "odometry", *services)]
    latest: dict[str, object] = {}
    camera = TruthCamera(robot.config, random.Random(11))

    async def keep(topic: keys.Topic) -> None:
        async for msg in node.subscribe(topic):
            latest[topic.name] = msg

    tasks = [asyncio.create_task(play_camera(node, camera, on_truth=lambda t, _: latest.update(truth=t)))]
    tasks += [asyncio.create_task(keep(t)) for t in
                                             (keys.SLAM_POSE, keys.SLAM_MAP, keys.MAP_LANDMARKS)]
    wanted = {"slam": ("slam/pose", "slam/map"), "mapper": ("map/landmarks",)}
    need = [k for s in services for k in wanted.get(s, ())] + (student or [])
    await wait_for(lambda: all(k in latest for k in need), timeout=90)
    await drive_legs(node, TOUR)
    stamp = latest["truth"].stamp
    await wait_for(lambda: all(latest[k].stamp >= stamp - 50_000_000 for k in need), timeout=30)
    for task in tasks:
        task.cancel()
    latest["procs"] = procs
    return latest


def points(lm: m.LandmarkMap) -> dict[int, tuple[float, float]]:
    return {p.id: (p.x, p.y) for p in lm.landmarks}


@pytest.mark.timeout(400)
async def test_reference_map_maker_and_slam_against_the_truth(make_robot) -> None:
    robot = make_robot(SIM)
    async with robot.node("tester") as node:
        got = await tour(robot, node, ("slam", "mapper"))
    check_exits(got["procs"])
    truth: m.Truth = got["truth"]
    made = score_map(points(got["map/landmarks"]), TRUE)
    slam = score_map(points(got["slam/map"]), TRUE)
    pose: m.PoseEstimate = got["slam/pose"]
    (px, py), = slam.alignment.apply(np.array([[pose.x, pose.y]]))
    pos_err = math.hypot(px - truth.x, py - truth.y)
    head_err = abs(wrap_angle(pose.theta + slam.alignment.rotation - truth.theta))
    print(f"\nmap maker: {len(made.errors)} landmarks, RMSE {made.rmse * 100:.2f} cm (raw {made.rmse_raw * 100:.2f})"
          f"\nSLAM: {len(slam.errors)} landmarks, RMSE {slam.rmse * 100:.2f} cm; final pose "
          f"{pos_err * 100:.2f} cm {math.degrees(head_err):.2f} deg")
    assert len(made.errors) >= 4 and made.rmse <= 0.05 and made.rmse_raw <= 0.05 and not made.spurious
    assert len(slam.errors) >= 4 and slam.rmse <= 0.05 and not slam.spurious
    assert pos_err <= 0.05 and head_err <= math.radians(3)
    for lm in got["slam/map"].landmarks + got["map/landmarks"].landmarks:  # covariances: 2x2, symmetric, positive
        c = np.array(lm.covariance).reshape(2, 2)
        assert np.allclose(c, c.T) and np.all(np.linalg.eigvalsh(c) > 0)
    assert len(pose.covariance) == 9


@pytest.mark.timeout(300)
async def test_hostile_sightings_one_line_each_and_bounded_maps(make_robot) -> None:
    """Made-up ids (a flood), impossible ranges and NaN: the services keep running, say so in few lines,
    and the maps stay within max_landmarks."""
    robot = make_robot(SIM + "[slam]\nmax_landmarks = 20\n[mapper]\nmax_landmarks = 20\n")
    procs = [robot.start(s) for s in ("slam", "mapper")]
    async with robot.node("tester") as node:
        maps: dict[str, m.LandmarkMap] = {}

        async def keep(topic: keys.Topic) -> None:
            async for msg in node.subscribe(topic):
                maps[topic.name] = msg

        tasks = [asyncio.create_task(keep(t)) for t in (keys.SLAM_MAP, keys.MAP_LANDMARKS)]
        await wait_for(lambda: all("slam: up to" in p.output or "mapper: known pose" in p.output for p in procs),
                       timeout=90)
        truth, cam = node.publisher(keys.TRUTH), node.publisher(keys.LANDMARKS)  # the test is the simulator
        key = node.key(keys.LANDMARKS)
        stamp = time.time_ns()
        for k in range(3000):  # 3000 made-up ids, bad ranges, NaN in raw bytes
            stamp += 1_000_000
            truth.put(m.Truth(stamp=stamp, x=0.0, y=0.0, theta=0.0))
            cam.put(m.Landmarks(stamp=stamp, landmarks=[m.Landmark(id=k, range=1.0 + k % 7 * 0.1, bearing=0.1),
                                                        m.Landmark(id=5, range=-3.0, bearing=0.0)]))
            if k % 100 == 0:
                node.session.put(key, b'{"stamp": 1, "landmarks": [{"id": 1, "range": NaN, "bearing": 0}]}')
            if k % 20 == 0:
                await asyncio.sleep(0.01)
        await wait_for(lambda: len(maps) == 2 and all(len(v.landmarks) == 20 for v in maps.values()), timeout=60)
        for task in tasks:
            task.cancel()
    for proc in procs:  # both slam and mapper
        assert proc.alive(), proc.output
        assert proc.stop() == 0, proc.output
        lines = proc.output.splitlines()
        assert any("not a sighting" in line for line in lines), proc.output
        assert sum("not a sighting" in line for line in lines) <= 40, proc.output  # rate-limited, 1 a second
        assert len(lines) < 200, proc.output


STUDENT = '''
"""A student's map maker: the mean of every sighting of a landmark from the true pose (no covariance)."""
import asyncio, math
from icefloe.runtime import Node, run
from icefloe.schemas import keys, messages as m

async def main(config):
    sums, pose = {}, None
    async with Node("my_mapper", config) as node:
        out = node.publisher(keys.MAP_LANDMARKS)

        async def poses():
            nonlocal pose
            async for t in node.subscribe(keys.TRUTH):
                pose = t

        async def frames():
            async for f in node.subscribe(keys.LANDMARKS, latest=False):
                if pose is None:
                    continue
                for lm in f.landmarks:
                    a = pose.theta + lm.bearing
                    s = sums.setdefault(lm.id, [0.0, 0.0, 0])
                    s[0] += pose.x + lm.range * math.cos(a); s[1] += pose.y + lm.range * math.sin(a); s[2] += 1
                out.put(m.LandmarkMap(stamp=f.stamp, landmarks=[
                    m.MapLandmark(id=i, x=sx / n, y=sy / n) for i, (sx, sy, n) in sorted(sums.items())]))

        await asyncio.gather(poses(), frames())

if __name__ == "__main__":
    run(main)
'''


@pytest.mark.timeout(400)
async def test_a_students_map_maker_replaces_the_reference_one(make_robot, tmp_path) -> None:
    """A config swap: ``services`` without ``mapper``, a ``[programs.my_mapper]`` of the student's that
    publishes the same key (map/landmarks), started with the command and environment `icefloe up`
    gives it. The scoring that holds the reference to 5 cm holds the student's too."""
    (tmp_path / "my_mapper.py").write_text(STUDENT)
    robot = make_robot('services = ["sim", "hwbridge", "odometry"]\n' + SIM +
                       '[programs.my_mapper]\ncommand = ["{python}", "my_mapper.py"]\n'
                       f'cwd = "{tmp_path}"\n')
    config = robot.config
    assert "mapper" not in config.services and "my_mapper" in config.programs
    program = config.programs["my_mapper"]
    command = [sys.executable if part == "{python}" else str(Path(program.cwd) / part) for part in program.command]
    env = {**robot.env, **program_environment(config, robot.config_path, "my_mapper"), **program.env}
    student = Proc("my_mapper", command, tmp_path / "my_mapper.log", env)
    robot.procs.append(student)
    async with robot.node("tester") as node:
        got = await tour(robot, node, (), student=["map/landmarks"])
    assert student.alive(), student.output
    score = score_map(points(got["map/landmarks"]), TRUE)
    print(f"\nthe student's map maker: {len(score.errors)} landmarks, RMSE {score.rmse * 100:.2f} cm")
    assert len(score.errors) >= 4 and score.rmse <= 0.05
