"""Helpers shared by the hwbridge integration tests (no tests here: real sim + hwbridge processes)."""

from __future__ import annotations

import asyncio
import contextlib
import math
import time

from conftest import Robot, wait_for

from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m


async def sim_state(node: Node, action: str = "read", **fields: object) -> m.SimState:
    return await node.query(keys.SIM_CONTROL, m.SimControl(action=action, **fields), timeout=5.0)


async def stood(node: Node, still_s: float = 0.2, timeout: float = 60.0) -> m.SimState:
    """The simulator's state once the board gives zero duty and no wheel count has changed for
    ``still_s`` of simulated time: the robot truly stands (a wall-clock sleep is not enough where
    the simulator runs slower than real time, as the gateware's does on a busy machine)."""
    deadline = time.monotonic() + timeout
    while True:
        state = await sim_state(node)
        if state.zero_duty_since >= 0 and state.sim_time - state.counts_changed >= still_s:
            return state
        assert time.monotonic() < deadline, f"the robot does not stand: {state}"
        await asyncio.sleep(0.05)


async def start_stack(robot: Robot, node: Node):
    """Start the simulator and hwbridge; return them once hw/wheels flows."""
    sim = robot.start("sim")
    hw = robot.start("hwbridge")
    wheels = node.subscribe(keys.WHEELS)
    got: list[m.Wheels] = []

    async def first() -> None:
        got.append(await anext(wheels))

    task = asyncio.ensure_future(first())
    try:
        await wait_for(lambda: task.done() or not hw.alive() or not sim.alive(), timeout=60)
    finally:
        task.cancel()
    assert hw.alive(), hw.output
    assert sim.alive(), sim.output
    wheels.close()
    return sim, hw


@contextlib.asynccontextmanager
async def driving(node: Node, v: float, w: float = 0.0, rate_hz: float = 20.0):
    """Publish ``cmd/twist`` at ``rate_hz`` inside the block; yields a dict with the last send time."""
    pub = node.publisher(keys.TWIST)
    sent = {"last": 0.0, "last_wall_ns": 0, "count": 0, "max_gap": 0.0}

    async def loop() -> None:
        while True:
            # The time before the put: a busy machine may let hwbridge receive the command before
            # put() returns to us, and the deadman counts from its receipt.
            wall_ns = time.time_ns()
            pub.put(m.Twist(v=v, w=w))
            if sent["count"]:
                sent["max_gap"] = max(sent["max_gap"], time.monotonic() - sent["last"])
            sent["last"] = time.monotonic()
            sent["last_wall_ns"] = wall_ns
            sent["count"] += 1
            await asyncio.sleep(1.0 / rate_hz)

    task = asyncio.ensure_future(loop())
    try:
        yield sent
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


async def forward_motion(node: Node, seconds: float) -> tuple[float, float, float]:
    """The simulated robot's true forward travel over ``seconds`` (from sim/control reads):
    (metres, simulated seconds, wall seconds). The two times differ when the simulation
    falls behind on a starved machine."""
    a = await sim_state(node)
    await asyncio.sleep(seconds)
    b = await sim_state(node)
    heading = (a.theta + b.theta) / 2
    travel = (b.x - a.x) * math.cos(heading) + (b.y - a.y) * math.sin(heading)
    # Both stamped by the simulator as it read its state.
    return travel, b.sim_time - a.sim_time, (b.stamp - a.stamp) * 1e-9


async def measured_forward_speed(node: Node, seconds: float) -> float:
    """True forward speed of the simulated robot over ``seconds`` of simulated time, m/s."""
    travel, sim_dt, wall_dt = await forward_motion(node, seconds)
    assert sim_dt > 0.5 * wall_dt, "the simulation clock is not keeping up"
    return travel / sim_dt


async def fresh(sub, after_ns: int):
    """The first message of ``sub`` stamped after ``after_ns`` (wall-clock ns)."""
    async for msg in sub:
        if msg.stamp > after_ns:
            return msg
    raise AssertionError(f"{sub.key_expr} ended")


async def deadman_delay(wheels, last_command_ns: int) -> float:
    """Seconds from the last command to the first ``hw/wheels`` sample with zero targets.

    ``wheels`` is a FIFO subscription to hw/wheels; ``last_command_ns`` the wall-clock
    time the last command was published.
    """
    async for w in wheels:
        if w.stamp > last_command_ns and w.target_left == 0.0 and w.target_right == 0.0:
            return (w.stamp - last_command_ns) * 1e-9
    raise AssertionError("hw/wheels ended")
