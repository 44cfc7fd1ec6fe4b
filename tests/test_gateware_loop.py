"""Gateware in the loop: hwbridge -> SPI -> the gateware -> the world -> the gateware -> hwbridge -> odometry.

Real processes (simulator, hwbridge, odometry) and real Zenoh, with the
simulator running the icoBoard as its compiled gateware (``[sim] icoboard =
"gateware"``): every frame hwbridge sends is clocked bit by bit through the
gateware's SPI pins, the world's motors run on its PWM pins and its encoder
pins follow the world's wheels.
"""

from __future__ import annotations

import asyncio
import math
import os
import re
import signal
import time

import pytest
from conftest import wait_for
from test_hwbridge_helpers import fresh, sim_state, start_stack, stood

from icefloe.gateware.cxxsim import CompiledBoard
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.hwbridge.shm import Shared, block_name
from icefloe.wire.icoboard import Peripherals

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]  # the first compile of the gateware

GATEWARE = ('[board]\nkind = "icoboard"\nbackend = "sim"\nprotocol = 2\n'
            '[sim]\nicoboard = "gateware"\nseed = 1\n'
            'profile = "ideal"\n')  # the subject is the gateware's counts, not the realistic wheels' slip


@pytest.fixture(scope="module", autouse=True)
def compiled() -> None:
    """Compile the gateware once here, so the simulator process finds it in the cache."""
    from icefloe import config as config_mod

    sim = config_mod.load(None).sim
    CompiledBoard(Peripherals(), clk_hz=sim.gateware_clk_hz).close()


async def _drive(node, poses, v: float, arrived) -> None:
    """``cmd/twist`` at ``v`` m/s until odometry says ``arrived(pose)``, then ``cmd/stop``."""
    twist = node.publisher(keys.TWIST)
    deadline = time.monotonic() + 60
    async for pose in poses:
        if arrived(pose):
            break
        twist.put(m.Twist(v=v, w=0.0))
        assert time.monotonic() < deadline, f"odometry at {pose} after 60 s"
    node.publisher(keys.STOP).put(m.Stop())


async def test_odometry_follows_the_truth_through_the_gateware(make_robot) -> None:
    robot = make_robot(GATEWARE)
    async with robot.node() as node:
        sim, hw = await start_stack(robot, node)
        odometry = robot.start("odometry")
        poses = node.subscribe(keys.ODOM_POSE)
        loops = node.subscribe(keys.LOOP)
        await asyncio.wait_for(anext(poses), 20)
        start = await sim_state(node)
        wall = time.monotonic()
        path, x = 0.0, start.x
        for v, arrived in ((0.2, lambda pose: pose.x >= 1.0), (-0.2, lambda pose: pose.x <= 0.0)):
            await _drive(node, poses, v, arrived)      # 1 m forward, then back
            truth = await stood(node)                  # stopped, on the truth
            pose = await fresh(poses, truth.stamp)
            assert abs(truth.x - x) > 0.95, truth      # it went 1 m
            path += abs(truth.x - x)
            x = truth.x
            error = math.hypot(pose.x - truth.x, pose.y - truth.y)
            assert error <= 0.01 * path, (pose, truth)
        realtime = (truth.sim_time - start.sim_time) / (time.monotonic() - wall)
        loop = await anext(loops)
        print(f"\ngateware in the loop: odometry error {error * 1e3:.1f} mm after {path:.2f} m; "
              f"simulated/real time {realtime:.2f}; hw/loop {loop}")
        assert loop.crc_errors == 0 and loop.board_errors == 0, loop
        assert truth.bad_frames == 0, truth
        # The watchdog trips only when the board heard nothing for 50 ms: when the simulator's
        # process was starved long enough that hwbridge gave the link up (and then took its
        # counts up again: the odometry check above holds either way).
        assert truth.watchdog_trips == 0 or "board link lost" in hw.output, (truth, hw.output)
        if truth.watchdog_trips:
            print(f"starved: the link was lost and the board's watchdog tripped {truth.watchdog_trips} times")
        assert odometry.alive() and sim.alive() and hw.alive()


async def test_sigkill_hwbridge_and_the_gateware_watchdog_stops_the_wheels(make_robot) -> None:
    robot = make_robot(GATEWARE)
    async with robot.node() as node:
        sim, hw = await start_stack(robot, node)
        node.publisher(keys.TWIST).put(m.Twist(v=0.2, w=0.0))
        await wait_for(lambda: True, timeout=0.1)
        deadline = time.monotonic() + 10
        while (await sim_state(node)).duty_left <= 0:
            node.publisher(keys.TWIST).put(m.Twist(v=0.2, w=0.0))
            assert time.monotonic() < deadline, "the wheels never got a duty"
            await asyncio.sleep(0.05)
        before = await sim_state(node)
        os.killpg(hw.popen.pid, signal.SIGKILL)     # the bus process and the cycle, at once
        hw.popen.wait()
        await wait_for(lambda: "PWM pins low" in sim.output, timeout=10)
        state = await sim_state(node)
        Shared.create(block_name(robot.name)).close()  # remove the block the kill left behind
        assert (state.duty_left, state.duty_right) == (0.0, 0.0)
        assert state.watchdog_trips == before.watchdog_trips + 1
        after_ms = float(re.search(r"PWM pins low ([\d.]+) ms after", sim.output).group(1))
        print(f"\ngateware watchdog: PWM pins low {after_ms:.3f} ms after the last valid frame")
        assert after_ms <= 50.0 + 1e3 / robot.config.board.pwm_hz
