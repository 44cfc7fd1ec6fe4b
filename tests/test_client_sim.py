"""`icefloe.client` against the simulated robot: real sim, hwbridge, odometry, info, power processes.

What a client call claims is checked on the robot itself: where the simulator's ground truth
says the robot went, which LEDs the board model has lit, what hwbridge commands the wheels.
Button presses and DIP switches go through the simulator's test handles (``sim/control``),
the way a finger would.
"""

from __future__ import annotations

import asyncio
import logging
import math
import signal
import subprocess
import sys
import threading
import time

import pytest
from conftest import ROOT, wait_for
from test_hwbridge_helpers import sim_state

from icefloe.client import AsyncRobot, Robot
from icefloe.errors import MotionStopped, MotionTimeout
from icefloe.schemas import keys
from icefloe.schemas import messages as m

pytestmark = pytest.mark.slow


def start(robot, *services: str) -> None:
    for service in ("sim", "hwbridge", *services):
        robot.start(service)


async def started(robot, node, *services: str) -> None:
    """Wait until the simulator, hwbridge and ``services`` are alive and hw/wheels flows."""
    names = ("sim", "hwbridge", *services)
    await wait_for_async(lambda alive: all(f"icefloe/{robot.name}/alive/{s}" in alive for s in names),
                         node.alive, timeout=30)
    wheels = node.subscribe(keys.WHEELS)
    await asyncio.wait_for(anext(wheels), 30)
    wheels.close()


def along(a: m.SimState, b: m.SimState) -> float:
    """How far the truth moved from ``a`` to ``b`` along ``a``'s heading, m."""
    return (b.x - a.x) * math.cos(a.theta) + (b.y - a.y) * math.sin(a.theta)


def turned(a: m.SimState, b: m.SimState) -> float:
    return math.degrees(math.remainder(b.theta - a.theta, math.tau))


async def test_forward_and_turn_get_there_by_odometry(robot):
    start(robot, "odometry", "info", "localizer")
    async with robot.node() as node, AsyncRobot(config=robot.config, timeout=10) as r:
        await started(robot, node, "odometry", "info", "localizer")
        await r.ready(keys.ODOM_POSE.name)
        sent = [node.subscribe(keys.WHEELS_CMD, latest=False, maxsize=10_000),
                node.subscribe(keys.STOP, latest=False, maxsize=10_000)]
        t0 = await sim_state(node)
        pose = await r.forward(0.3)
        await asyncio.sleep(0.3)  # the truth has settled
        t1 = await sim_state(node)
        print(f"forward(0.3): truth {along(t0, t1):.4f} m, odometry {pose.x:.4f} m")
        assert along(t0, t1) == pytest.approx(0.3, abs=0.01)
        assert abs(pose.v) < 0.01  # it returned at rest

        await r.turn(math.radians(90))
        await asyncio.sleep(0.3)
        t2 = await sim_state(node)
        print(f"turn(90°): truth {turned(t1, t2):.2f}°")
        # Within 3° or so on an idle machine; a loaded one hears odometry late and stops late.
        assert turned(t1, t2) == pytest.approx(90, abs=8)

        await r.forward(-0.1, 0.05)
        await asyncio.sleep(0.3)
        t3 = await sim_state(node)
        assert along(t2, t3) == pytest.approx(-0.1, abs=0.01)

        # Every speed and stop of the moves numbered and stamped by this client (the stop that
        # ends a move wins over speeds sent before it, whatever their priorities).
        commands = []
        for sub in sent:
            while sub.pending():
                commands.append(await anext(sub))
        assert commands and {c.sender for c in commands} == {str(r.node.session.zid())}
        assert len({c.seq for c in commands}) == len(commands) and min(c.stamp for c in commands) > 0
        stops = sorted(c.seq for c in commands if isinstance(c, m.Stop))
        assert len(stops) >= 3, stops  # one at the end of each move at least

        # The localizer's pose in the map (no markers needed: it follows odometry in between).
        estimate = r.localized_pose
        assert isinstance(estimate, m.PoseEstimate) and len(estimate.covariance) == 9


async def test_forward_times_out_on_a_blocked_wheel_and_stops_the_wheels(robot):
    start(robot, "odometry", "info")
    async with robot.node() as node, AsyncRobot(config=robot.config, timeout=10) as r:
        await started(robot, node, "odometry", "info")
        await r.ready(keys.ODOM_POSE.name, keys.WHEELS.name)
        await sim_state(node, "stall", wheel="left", on=True)
        await sim_state(node, "stall", wheel="right", on=True)
        begun = time.monotonic()
        with pytest.raises(MotionTimeout, match=r"forward\(0.3 m\): 0.00\d m done after 1.5 s \(timeout\); "
                                                 r"stopped. A wheel blocked"):
            await r.forward(0.3, timeout=1.5)
        assert time.monotonic() - begun < 4
        # hwbridge commands nothing any more.
        await wait_for(lambda: r.wheels.target_left == 0 and r.wheels.target_right == 0, timeout=5)


async def test_a_stop_from_another_program_ends_forward(robot):
    start(robot, "odometry", "info")
    async with robot.node() as node, AsyncRobot(config=robot.config, timeout=10) as r:
        await started(robot, node, "odometry", "info")
        await r.ready(keys.ODOM_POSE.name)
        move = asyncio.create_task(r.forward(1.0))
        await wait_for(lambda: r.pose.v > 0.05, timeout=10)
        node.publisher(keys.STOP).put(m.Stop())
        with pytest.raises(MotionStopped, match=r"forward\(1.0 m\): ended by a cmd/stop from another program "
                                                 r"after 0.\d+ m"):
            await move
        await asyncio.sleep(1.0)
        still = await sim_state(node)
        assert abs(still.speed_left) < 0.005 and abs(still.speed_right) < 0.005


async def test_ctrl_c_in_a_blocking_forward_stops_the_robot(robot):
    """SIGINT while `Robot.forward` blocks: the script gets KeyboardInterrupt, the wheels a stop."""
    start(robot, "odometry", "info")
    script = ("import sys\nfrom icefloe import Robot\n"
              f"with Robot(config={str(robot.config_path)!r}, timeout=10) as robot:\n"
              "    robot.pose\n    print('moving', flush=True)\n    robot.forward(2.0)\n")
    async with robot.node() as node:
        await started(robot, node, "odometry", "info")
        stops: list[float] = []

        async def record() -> None:
            async for _ in node.subscribe(keys.STOP, latest=False):
                stops.append(time.monotonic())

        recorder = asyncio.create_task(record())
        await asyncio.sleep(0.3)
        proc = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
        try:
            assert (await asyncio.to_thread(proc.stdout.readline)).strip() == "moving"
            state = await sim_state(node)
            while state.speed_left < 0.05:
                await asyncio.sleep(0.05)
                state = await sim_state(node)
            assert stops == []
            proc.send_signal(signal.SIGINT)
            interrupted = time.monotonic()
            out = (await asyncio.to_thread(proc.communicate, timeout=20))[0]
        finally:
            if proc.poll() is None:
                proc.kill()
        recorder.cancel()
        assert proc.returncode != 0 and "KeyboardInterrupt" in out, out
        # The deadman would stop the wheels too, but it sends no cmd/stop: this one is the client's.
        assert stops and stops[0] - interrupted < 5.0, "no cmd/stop after Ctrl-C"
        await asyncio.sleep(1.0)
        still = await sim_state(node)
        assert abs(still.speed_left) < 0.005 and abs(still.speed_right) < 0.005


async def test_out_of_range_arguments_name_the_robots_limit_and_move_nothing(robot):
    start(robot, "info")
    async with robot.node() as node, AsyncRobot(config=robot.config) as r:
        await started(robot, node, "info")
        info_key = f"icefloe/{robot.name}/info"
        limit = rf"max_wheel_speed, 0.5 m/s \({info_key}\)"
        with pytest.raises(ValueError, match=rf"left: 5.0 m/s is beyond this robot's {limit}"):
            await r.set_velocity(5, 5, duration=1)
        with pytest.raises(ValueError, match=rf"right: -0.6 m/s is beyond this robot's {limit}"):
            await r.set_velocity(0.1, -0.6)
        half = robot.config.geometry.track / 2  # the robot's own (sim.toml's calibrated track)
        with pytest.raises(ValueError, match=rf"drive: v=0.4 m/s, w=3.0 rad/s needs a wheel at {0.4 + 3 * half:.3f} "
                                             rf"m/s, beyond this robot's {limit}; at w=3.0 rad/s \|v\| can be "
                                             rf"{0.5 - 3 * half:.3f} m/s at most, and \|w\| is at most "
                                             rf"{0.5 / half:.2f} rad/s"):
            await r.drive(0.4, 3.0)
        with pytest.raises(ValueError, match=rf"speed: 0.8 m/s is beyond this robot's {limit}"):
            await r.forward(1.0, 0.8)
        with pytest.raises(ValueError, match=rf"speed: 7.0 rad/s needs the wheels at {7 * half:.3f} m/s, "
                                             rf".*at most {0.5 / half:.2f}"):
            await r.turn(1.0, 7.0)
        with pytest.raises(ValueError, match=r"speed: must be > 0 m/s \(the sign of distance says which way\)"):
            await r.forward(0.1, -0.1)
        with pytest.raises(ValueError, match=r"blink: each time must be >= 0.05 s"):
            await r.led(2, blink=0.01)
        with pytest.raises(ValueError, match=r"led: expected 1 \(red\) or 2..4"):
            await r.led(5)
        assert (await r.info()).max_wheel_speed == 0.5
        await asyncio.sleep(0.5)
        state = await sim_state(node)
        assert state.duty_left == 0 and state.duty_right == 0 and state.speed_left == 0


async def test_buttons_and_dip_from_the_board(robot, caplog):
    """S4 (a press counter in the firmware) and the shutdown button (a GPIO line the power service
    reads) reach gpiozero-style callbacks on the blocking Robot's callback thread."""
    start(robot, "power")
    async with robot.node() as node:
        await started(robot, node, "power")
        r = await asyncio.to_thread(Robot, config=robot.config_path, timeout=10)
        try:
            s4, sdn = r.buttons["S4"], r.buttons[10]
            events: list[tuple[str, str, str]] = []
            s4.when_pressed = lambda button: events.append(("pressed", button.name, threading.current_thread().name))
            sdn.when_pressed = lambda: events.append(("pressed", "SDN", threading.current_thread().name))
            sdn.when_released = lambda: events.append(("released", "SDN", threading.current_thread().name))
            with pytest.raises(ValueError, match=r"S4\.when_released: S4 reports presses only"):
                s4.when_released = print
            with pytest.raises(ValueError, match="when_pressed: expected a function"):
                s4.when_pressed = 3

            await asyncio.sleep(0.5)  # io/buttons subscribers declared on the router
            await sim_state(node, "press_button", button=3, seconds=0.05)
            await wait_for(lambda: events, timeout=10)
            assert events == [("pressed", "S4", "icefloe-callbacks_0")]
            assert s4.presses == 1 and s4.is_pressed is None

            await sim_state(node, "press_button", button=10, seconds=0.15)  # short: no shutdown
            await wait_for(lambda: len(events) == 3, timeout=10)
            assert [e[:2] for e in events[1:]] == [("pressed", "SDN"), ("released", "SDN")]
            assert sdn.is_pressed is False and sdn.presses == 1

            # A callback that raises is logged with its traceback; the next press calls it again.
            def broken() -> None:
                events.append(("broken", "S4", ""))
                raise RuntimeError("a student's bug")

            s4.when_pressed = broken
            with caplog.at_level(logging.ERROR, logger="icefloe.client"):
                for _ in range(2):
                    await sim_state(node, "press_button", button=3, seconds=0.05)
                    await asyncio.sleep(0.3)
                await wait_for(lambda: events.count(("broken", "S4", "")) == 2, timeout=10)
            failures = [rec for rec in caplog.records if "callback" in rec.getMessage()]
            assert failures and "broken" in failures[0].getMessage() and failures[0].exc_info

            waiter = asyncio.create_task(asyncio.to_thread(r.wait_for_press, "S4", 10))
            await asyncio.sleep(0.3)
            await sim_state(node, "press_button", button=3, seconds=0.05)
            assert await waiter is True
            assert await asyncio.to_thread(r.wait_for_press, "S4", 0.2) is False

            assert await asyncio.to_thread(lambda: r.dip) == 1  # the simulator's power-on switches
            await sim_state(node, "set_dip", dip=9)
            await wait_for(lambda: r.dip == 9, timeout=10)
        finally:
            await asyncio.to_thread(r.close)


async def test_leds_light_and_blink_on_the_board(robot):
    start(robot)
    async with robot.node() as node, AsyncRobot(config=robot.config) as r:
        await started(robot, node)

        async def lit() -> int:
            return (await sim_state(node)).leds

        await r.led(2)
        await wait_for_async(lambda v: v & 0b0010, lit)
        await r.led(3, blink=0.1)
        seen = set()
        for _ in range(40):  # sample the board for about 2 s: LED 3 goes on and off
            seen.add(await lit() & 0b0100)
            await asyncio.sleep(0.05)
        assert seen == {0, 0b0100}
        await r.led(3, False)  # ends the blink
        await asyncio.sleep(0.5)
        assert not any([(await lit()) & 0b0100 for _ in range(10)])
        assert (await lit()) & 0b0010  # LED 2 stayed on

        await r.led(4, blink=(0.05, 0.05), times=2)  # a bounded blink ends dark
        await asyncio.sleep(0.6)
        assert r.leds[4] is False
        await r.led(2, blink=0.2)
    # Closing the client ends its blinks dark.
    await asyncio.sleep(0.5)
    assert not (await lit_after(robot)) & 0b0010


async def lit_after(robot) -> int:
    async with robot.node("reader") as node:
        return (await sim_state(node)).leds


async def wait_for_async(accept, read, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not accept(await read()):
        assert time.monotonic() < deadline, "condition not met"
        await asyncio.sleep(0.05)
