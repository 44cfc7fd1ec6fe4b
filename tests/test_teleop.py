"""`icefloe teleop` in a pseudo-terminal against the simulated robot: keys drive it, the simulator's
truth moves; space, the deadman, the terminal losing focus and quitting each stop it."""

from __future__ import annotations

import asyncio
import math
import sys

import pytest
from conftest import ROOT, Robot
from terminal import Terminal

from icefloe.cli.teleop import FOCUS_OUT, Drive, split_keys
from icefloe.schemas import keys
from icefloe.schemas import messages as m


def test_keys_set_the_motion_and_the_deadman_stops_it() -> None:
    drive = Drive(speed=0.2, turn=1.0, max_speed=0.5, max_turn=6.0, hold=0.8)
    assert drive.key(b"w", 0.0) == "move" and (drive.v, drive.w) == (0.2, 0.0)
    assert drive.key(b"\x1b[D", 0.1) == "move" and (drive.v, drive.w) == (0.0, 1.0)  # left arrow
    assert drive.key(b"q", 0.2) == "move" and (drive.v, drive.w) == (0.2, 1.0)
    assert drive.key(b"+", 0.3) == "move" and drive.v == pytest.approx(0.25) and drive.w == pytest.approx(1.25)
    for _ in range(10):
        drive.key(b"+", 0.4)
    assert drive.speed == 0.5 and drive.turn == 6.0  # never past the robot's limits
    assert not drive.expired(1.0)
    assert drive.expired(1.3) and not drive.moving and "no key for 0.8 s" in drive.doing
    drive.key(b"s", 2.0)
    assert drive.key(b" ", 2.1) == "stop" and not drive.moving
    drive.key(b"d", 2.2)
    assert drive.key(FOCUS_OUT, 2.3) == "stop" and "lost focus" in drive.doing
    assert drive.key(b"\x1b", 2.4) == "quit"
    assert split_keys(b"w\x1b[Aa\x1b[O ") == [b"w", b"\x1b[A", b"a", FOCUS_OUT, b" "]


async def sim_state(node) -> m.SimState:
    return await node.query(keys.SIM_CONTROL, m.SimControl(action="read"), timeout=5.0)


async def wheels_stopped(node, timeout: float = 3.0) -> m.SimState:
    """Wait until the simulated wheels' true speeds are zero. (Not the duty: the PenguinPi firmware, and its
    model, keep the PI integrator when the demand drops to 0, which leaves a small duty that friction holds.)"""
    deadline = asyncio.get_running_loop().time() + timeout
    while True:
        state = await sim_state(node)
        if abs(state.speed_left) + abs(state.speed_right) < 1e-3:
            return state
        if asyncio.get_running_loop().time() > deadline:
            raise AssertionError(f"wheels still turning {timeout} s later: {state}")
        await asyncio.sleep(0.05)


async def hold_key(term: Terminal, key: str, seconds: float) -> None:
    """A key held down: the terminal repeats it (about 30 times a second)."""
    end = asyncio.get_running_loop().time() + seconds
    while asyncio.get_running_loop().time() < end:
        term.send(key)
        await asyncio.sleep(0.03)


async def moved(node, since: m.SimState) -> float:
    now = await sim_state(node)
    return math.hypot(now.x - since.x, now.y - since.y)


@pytest.mark.slow
async def test_teleop_drives_the_simulated_robot_and_every_way_out_stops_it(robot: Robot) -> None:
    for service in ("sim", "hwbridge"):
        robot.start(service)
    async with robot.node("tester") as node:
        await asyncio.wait_for(anext(node.subscribe(keys.WHEELS)), 60)  # hwbridge drives the board: up
        start = await asyncio.wait_for(retry_state(node), 40)
        term = await asyncio.to_thread(Terminal, [sys.executable, "-m", "icefloe.cli", "teleop", "--config",
                                                  str(robot.config_path)], cwd=ROOT)
        try:
            await asyncio.to_thread(term.wait_for, "driving", 30)
            # Forward, held: the robot drives (truth moves forward), until space.
            await hold_key(term, "w", 1.5)
            assert await moved(node, start) > 0.05, term.text
            term.send(" ")
            stopped = await wheels_stopped(node)
            await asyncio.sleep(0.5)
            assert await moved(node, stopped) < 0.005  # and stays stopped
            # The deadman: one tap, then nothing: it stops by itself, teleop still running.
            term.send("w")
            await asyncio.sleep(0.3)
            assert abs((await sim_state(node)).speed_left) > 0.01
            stopped = await wheels_stopped(node, timeout=0.8 + 2.0)
            assert term.alive() and "no key for 0.8 s" in term.text
            # The terminal losing focus stops it at once (well before the deadman).
            await hold_key(term, "a", 0.6)
            assert abs((await sim_state(node)).speed_left) > 0.01
            term.send(FOCUS_OUT)
            await wheels_stopped(node, timeout=0.6)
            assert "lost focus" in term.text
            # Quitting with Ctrl-C while driving: teleop exits 0 and the robot stops.
            await hold_key(term, "\x1b[A", 0.6)  # the up arrow
            term.ctrl_c()
            assert await asyncio.to_thread(term.wait, 15) == 0, term.text
            stopped = await wheels_stopped(node, timeout=1.0)
            await asyncio.sleep(1.0)
            assert await moved(node, stopped) < 0.005
        finally:
            term.kill()


async def retry_state(node) -> m.SimState:
    """The simulator's state once it answers (it takes a while to start on a busy machine)."""
    while True:
        try:
            return await sim_state(node)
        except Exception:
            await asyncio.sleep(0.2)
