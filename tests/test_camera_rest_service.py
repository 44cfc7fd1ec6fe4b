"""The camera at rest as a real process (issue 35): standing still in the simulator's realistic profile
(flicker, noise, exposure, JPEG, latency), it rests at ``camera.rest_detection_rate_hz``; the robot
turning ends the rest at once. The test plays the simulator: it publishes ``sim/truth``, the camera
renders from it (as test_camera_service.py does)."""

from __future__ import annotations

import asyncio
import itertools
import math
import time

from conftest import Robot, wait_for

from icefloe.schemas import keys
from icefloe.schemas import messages as m

POSE = (0.3, -0.2, 0.6)
"""Where the robot stands: markers in view."""
TURN_RATE = 0.5
"""rad/s, as bench/stack_cpu.py's drive."""


async def test_a_still_camera_rests_and_a_turn_brings_its_detections_back_at_once(make_robot) -> None:
    """Measured (2026-12-07, load average 2.9-3.2, three runs, 7.6-7.8 s each): gaps at rest 1.01-1.09 s,
    2 detections in 2.5 s of rest; the first detection 0.06-0.07 s after the turn began, 14 in its first
    second. Bounds: a rest gap of 0.8 s or more twice within 20 s; at most 4 detections in 2.5 s of rest;
    the first after the turn within 0.5 s, and 8 in its first second (fps 15)."""
    robot: Robot = make_robot('[sim]\nprofile = "realistic"\nseed = 3\n')
    assert robot.config.camera.rest_detection_rate_hz == 1.0 and robot.config.camera.fps == 15.0
    camera = robot.start("camera")
    x, y, theta0 = POSE
    turning_since: list[float] = []
    arrivals: list[float] = []
    async with robot.node("tester") as node:
        marks = node.subscribe(keys.LANDMARKS, latest=False, maxsize=1000)
        truth = node.publisher(keys.TRUTH)

        async def play_truth() -> None:  # the simulator: standing, then turning once asked
            while True:
                now = time.monotonic()
                turned = TURN_RATE * (now - turning_since[0]) if turning_since else 0.0
                truth.put(m.Truth(stamp=time.time_ns(), x=x, y=y, theta=math.remainder(theta0 + turned, math.tau),
                                  w=TURN_RATE if turning_since else 0.0))
                await asyncio.sleep(0.02)

        async def collect() -> None:
            async for _ in marks:
                arrivals.append(time.monotonic())

        tasks = [asyncio.create_task(play_truth()), asyncio.create_task(collect())]
        try:
            def rest_gaps() -> int:
                return sum(b - a >= 0.8 for a, b in itertools.pairwise(arrivals))

            await wait_for(lambda: rest_gaps() >= 2, timeout=40)  # first frames, then a second of full rate
            resting_from = arrivals[-1]
            await asyncio.sleep(2.5)  # the rest itself is the subject: its rate over a fixed window
            at_rest = [t for t in arrivals if t > resting_from]
            assert len(at_rest) <= 4, f"{len(at_rest)} detections in 2.5 s at rest: the flicker woke the camera"
            turning_since.append(time.monotonic())
            await wait_for(lambda: arrivals[-1] > turning_since[0], timeout=5)
            first = arrivals[-1] - turning_since[0]
            assert first < 0.5, f"the first detection came {first:.2f} s after the turn began"
            await wait_for(lambda: arrivals[-1] >= turning_since[0] + 1.0, timeout=10)
            turning = [t for t in arrivals if turning_since[0] < t <= turning_since[0] + 1.0]
            assert len(turning) >= 8, f"{len(turning)} detections in the turn's first second"
            print(f"\nrest gaps {[round(b - a, 2) for a, b in itertools.pairwise(arrivals) if b - a > 0.5]}"
                  f", at rest {len(at_rest)} in 2.5 s; turning: first after {first:.2f} s, {len(turning)} in 1 s")
        finally:
            for task in tasks:
                task.cancel()
    assert camera.stop() == 0
