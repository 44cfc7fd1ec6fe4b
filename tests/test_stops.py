"""A stop always wins: real simulator, hwbridge and webapi processes, judged by the simulator.

Every check is on the simulated robot itself (its PWM duty, the firmware's integrators,
the true encoder counts), not on what hwbridge says. A stop's confirmation is the reply
that says "stopped" (``cmd/halt``, ``/robot/stop``, a timed motion's answer): from then
on the board runs zero duty (``peak_duty`` stays 0 after a ``mark``) with its
controller cleared, until a command issued after the stop.
"""

from __future__ import annotations

import asyncio
import json
import os
import random
import signal
import time

import msgspec
import pytest
import zenoh
from test_hwbridge_helpers import sim_state, start_stack
from webapi_helpers import webapi, webapi_robot

from icefloe.schemas import keys
from icefloe.schemas import messages as m

pytestmark = pytest.mark.slow

ICO_V2 = '[board]\nkind = "icoboard"\nbackend = "sim"\nprotocol = 2\n'
CONFIRM_TIMEOUT = 10.0
"""Generous: the stack shares a loaded 2-core machine with other test suites."""
AFTER_S = {"penguinpi": 0.025, "icoboard": 0.005}
"""How long after a confirmation we watch for duty: past one PenguinPi control step (20 ms);
the icoBoard applies each frame at once (1 ms)."""
MOTION_PRIORITIES = (zenoh.Priority.INTERACTIVE_LOW, zenoh.Priority.DATA_HIGH, zenoh.Priority.DATA,
                     zenoh.Priority.DATA_LOW, zenoh.Priority.BACKGROUND)


class Sender:
    """Numbered, stamped commands on raw Zenoh, at any priority, as JSON or MessagePack."""

    def __init__(self, node, name: str) -> None:
        self.node, self.name, self.seq = node, name, 0
        self._wall0, self._mono0 = time.time_ns(), time.monotonic_ns()

    def fields(self, **extra: object) -> dict[str, object]:
        self.seq += 1
        stamp = self._wall0 + time.monotonic_ns() - self._mono0
        return {"sender": self.name, "seq": self.seq, "stamp": stamp, **extra}

    def put(self, topic: keys.Topic, fields: dict[str, object], priority: zenoh.Priority,
            as_json: bool, express: bool = False) -> None:
        payload = json.dumps(fields).encode() if as_json else msgspec.msgpack.encode(fields)
        encoding = "application/json" if as_json else "application/msgpack"
        self.node.session.put(self.node.key(topic), payload, encoding=encoding, priority=priority,
                              express=express)


async def loop_stats(node) -> m.LoopStats:
    loops = node.subscribe(keys.LOOP)
    try:
        return await asyncio.wait_for(anext(loops), 5.0)
    finally:
        loops.close()


LAGGED = []
"""Confirmations the simulator had not caught up with (see `after_confirmation`)."""


async def at_confirmation(node) -> m.SimState:
    """Right at a confirmation: zero duty and clear integrators; marks the board model, so
    that `nothing_since` sees any duty applied from here on.

    The board model runs on the simulator's clock, which falls behind the wall clock
    on a loaded machine (and catches up); the PenguinPi's confirmation counts 21 ms of
    wall time for the firmware's 20 ms control step. So when the model has not yet
    run that step, we let its clock run 21 ms (the exact timing is checked in simulated
    time in tests/test_hwbridge_stops.py) and count it.
    """
    now = await sim_state(node, "mark")
    if now.peak_duty != 0.0 or (now.integrator_left, now.integrator_right) != (0, 0):
        LAGGED.append(now)
        state, give_up = now, time.monotonic() + 10.0
        while state.sim_time <= now.sim_time + 0.021:
            assert time.monotonic() < give_up, "the simulator's clock stands still"
            await asyncio.sleep(0.002)
            state = await sim_state(node, "mark")
        now = state
    assert now.peak_duty == 0.0, f"duty {now.duty_left}, {now.duty_right} at the confirmation"
    assert (now.integrator_left, now.integrator_right) == (0, 0), now
    return now


async def nothing_since(node) -> m.SimState:
    """No duty at all since the last `at_confirmation` (``peak_duty`` since its mark)."""
    later = await sim_state(node)
    assert later.peak_duty == 0.0, f"the wheels were driven after the confirmation: {later}"
    return later


async def after_confirmation(node, board: str = "penguinpi") -> m.SimState:
    """`at_confirmation`, then no duty for one of the board's control steps after it."""
    await at_confirmation(node)
    await asyncio.sleep(AFTER_S[board])
    return await nothing_since(node)


WATCH_EVERY = 10
"""In the 1000-cycle tests, each stop's quiet time is checked right before the next cycle's
first command (whatever time the test took in between; that covers commands overtaken by
the stop, which arrive within milliseconds); every 10th also waits a full control step."""


async def quiet_until_next(node, cycle: int, board: str) -> None:
    """Between a cycle's confirmation and the next cycle's first command."""
    if cycle % WATCH_EVERY == 0:
        await asyncio.sleep(AFTER_S[board])
    await nothing_since(node)


async def test_1000_hold_then_stop_cycles_through_the_bus(make_robot) -> None:
    """A hold at low priorities, JSON or MessagePack, then a stop at real-time priority right
    behind it: the stop overtakes commands issued before it, which must not drive.

    On the icoBoard, whose stops are confirmed within a millisecond or two, so that the 1000
    cycles are quick (the PenguinPi's confirmation takes a 20 ms control step and more: its
    stops are checked in the every-kind test here and step by step in test_hwbridge_stops)."""
    rng = random.Random(15)
    robot = make_robot(ICO_V2)
    async with robot.node() as node:
        await start_stack(robot, node)
        sender = Sender(node, f"cycles-{os.getpid()}")
        waits: list[float] = []
        started = time.monotonic()
        for cycle in range(1000):
            if cycle:
                await quiet_until_next(node, cycle, "icoboard")
            speed = rng.uniform(0.05, 0.3)
            end = time.monotonic() + rng.uniform(0.0, 0.006)
            while True:  # the hold: commands every 1-3 ms, the last one right before the stop
                sender.put(keys.WHEELS_CMD, sender.fields(left=speed, right=speed * rng.uniform(0.5, 1.5)),
                           rng.choice(MOTION_PRIORITIES), rng.random() < 0.5, rng.random() < 0.3)
                if time.monotonic() >= end:
                    break
                await asyncio.sleep(rng.uniform(0.001, 0.003))
            stop = sender.fields()
            sender.put(keys.STOP, stop, zenoh.Priority.REAL_TIME, rng.random() < 0.5, express=True)
            t0 = time.monotonic()
            await node.query(keys.HALT, m.Halt(rest=False, **stop), timeout=CONFIRM_TIMEOUT)
            waits.append(time.monotonic() - t0)
            await at_confirmation(node)
        await quiet_until_next(node, 0, "icoboard")
        stats = await loop_stats(node)
    assert stats.commands_dropped > 0, "no command was overtaken: the race was not exercised"
    waits.sort()
    print(f"1000 cycles in {time.monotonic() - started:.1f} s; {stats.commands_dropped} commands "
          f"refused (issued before a stop); stop -> confirmation p50 {waits[500] * 1e3:.1f} ms, "
          f"p99 {waits[990] * 1e3:.1f} ms, max {waits[-1] * 1e3:.1f} ms; the simulator behind "
          f"{len(LAGGED)} times")


async def test_1000_hold_then_stop_cycles_through_the_webapi(make_robot) -> None:
    """As pibot_client: setVelocity(l, r) holds, stop() stops; between them the hold may be
    changed (/motor/set/velocity). After /robot/stop's answer nothing moves the wheels.

    The web API's commands do not depend on the board; on the icoBoard each confirmation
    takes a millisecond or two instead of the PenguinPi's 25-40 ms (see the bus test)."""
    rng = random.Random(16)
    robot = webapi_robot(make_robot, ICO_V2)
    async with robot.node() as node:
        await start_stack(robot, node)
        async with webapi(robot) as http:
            started = time.monotonic()
            for cycle in range(1000):
                if cycle:
                    await quiet_until_next(node, cycle, "icoboard")
                demand = rng.randint(10, 60)
                status, _, body = await http.get("/robot/set/velocity", value=f"{demand},{demand}")
                assert status == 200, body
                if rng.random() < 0.5:
                    await asyncio.sleep(rng.uniform(0.0, 0.005))
                    status, _, body = await http.get("/motor/set/velocity", id=rng.randint(0, 1),
                                                     value=rng.randint(10, 60))
                    assert status == 200, body
                status, _, body = await http.get("/robot/stop")
                assert status == 200, body
                await at_confirmation(node)
            await quiet_until_next(node, 0, "icoboard")
            elapsed = time.monotonic() - started
        stats = await loop_stats(node)
    print(f"1000 cycles in {elapsed:.1f} s; {stats.commands_dropped} commands refused")


@pytest.mark.parametrize("board", ["penguinpi", "icoboard"])
async def test_every_kind_of_stop_leaves_zero_duty_and_a_clear_controller(make_robot, board) -> None:
    robot = make_robot(ICO_V2 if board == "icoboard" else "")
    async with robot.node() as node:
        _sim, hw = await start_stack(robot, node)
        sender = Sender(node, "kinds")
        wheels_pub, stop_pub = node.publisher(keys.WHEELS_CMD), node.publisher(keys.STOP)

        async def drive(seconds: float) -> None:
            """Hold 0.2 m/s for ``seconds`` and until the board drives (the firmware's integrators
            filled): on a loaded machine the simulator or hwbridge can fall behind."""
            end, give_up = time.monotonic() + seconds, time.monotonic() + 30.0
            while True:
                wheels_pub.put(m.WheelSpeeds(**sender.fields(left=0.2, right=0.2)))
                await asyncio.sleep(0.05)
                if time.monotonic() < end:
                    continue
                state = await sim_state(node)
                if state.duty_left > 0.05 and (board != "penguinpi" or state.integrator_left != 0):
                    return
                assert time.monotonic() < give_up, f"the board was never driven: {state}"

        async def until_zero_duty(since: float, within: float) -> None:
            """For the stops nobody answers (the deadman): poll the truth."""
            while (await sim_state(node)).duty_left != 0.0:
                assert time.monotonic() - since < within, "no zero duty in time"
                await asyncio.sleep(0.002)

        # cmd/stop, confirmed by cmd/halt (rest = False) for the same stop
        await drive(0.3)
        stop = sender.fields()
        stop_pub.put(m.Stop(**stop))
        await node.query(keys.HALT, m.Halt(rest=False, **stop), timeout=CONFIRM_TIMEOUT)
        await after_confirmation(node, board)
        # cmd/halt alone (answers once the wheels are at rest)
        await drive(0.3)
        halted = await node.query(keys.HALT, m.Halt(**sender.fields()), timeout=CONFIRM_TIMEOUT)
        assert abs(halted.speed_left) < 0.005
        await after_confirmation(node, board)
        # a timed motion's end
        done = await node.query(keys.MOTION, m.Motion(**sender.fields(left=0.2, right=0.2,
                                                                      duration=0.3)),
                                timeout=CONFIRM_TIMEOUT)
        assert done.completed, done
        await after_confirmation(node, board)
        # the deadman: 0.5 s after the last command, then one control step (PenguinPi: 20 ms)
        await drive(0.3)
        last = time.monotonic()
        await until_zero_duty(last, 5.0)  # 0.5 s and a step; the exact time in test_hwbridge_stops
        await after_confirmation(node, board)
        # a command of zero speed
        await drive(0.3)
        wheels_pub.put(m.WheelSpeeds(**sender.fields(left=0.0, right=0.0)))
        await until_zero_duty(time.monotonic(), 5.0)
        await after_confirmation(node, board)
        # exit (SIGTERM), while commands keep coming
        await drive(0.3)
        wheels_pub.put(m.WheelSpeeds(**sender.fields(left=0.2, right=0.2)))
        assert hw.stop(signal.SIGTERM) == 0
        await asyncio.sleep(0.1)  # the firmware's next control step
        await after_confirmation(node, board)
        await asyncio.sleep(0.5)
        state = await sim_state(node)
        assert state.peak_duty == 0.0 and (state.integrator_left, state.integrator_right) == (0, 0)


async def test_a_stalled_bus_side_moves_nothing_when_it_wakes(robot) -> None:
    """hwbridge's bus process stopped (SIGSTOP) for 2 s while a client drives, then goes
    silent: what it sent meanwhile is older than the deadman when it is read, and drives
    nothing -- stamped by the client, or only by the router (a student's JSON)."""
    async with robot.node() as node:
        _sim, hw = await start_stack(robot, node)
        sender = Sender(node, "stalled")
        wheels_pub = node.publisher(keys.WHEELS_CMD)
        before = await loop_stats(node)

        def both(speed: float) -> None:
            wheels_pub.put(m.WheelSpeeds(**sender.fields(left=speed, right=speed)))
            node.session.put(node.key(keys.TWIST), json.dumps({"v": speed, "w": 0.0}),
                             encoding="application/json")

        for _ in range(20):
            both(0.2)
            await asyncio.sleep(0.05)
        assert (await sim_state(node)).duty_left > 0
        os.kill(hw.popen.pid, signal.SIGSTOP)
        try:
            stalled = time.monotonic()
            while time.monotonic() - stalled < 0.5:  # the client drives on for 0.5 s ...
                both(0.2)
                await asyncio.sleep(0.05)
            await asyncio.sleep(1.0)  # ... then is silent; the cycle's deadman has stopped the wheels
            parked = await sim_state(node, "mark")
            assert parked.peak_duty == 0.0 and max(abs(parked.speed_left), abs(parked.speed_right)) < 0.01
            await asyncio.sleep(2.0 - (time.monotonic() - stalled))
        finally:
            os.kill(hw.popen.pid, signal.SIGCONT)
        await asyncio.sleep(1.0)
        after = await sim_state(node)
        assert after.peak_duty == 0.0, after
        assert (after.ticks_left, after.ticks_right) == (parked.ticks_left, parked.ticks_right)
        stats = await loop_stats(node)
        assert stats.commands_dropped - before.commands_dropped >= 2 * 8, stats  # ~10 + 10 sent
        assert hw.alive()


@pytest.mark.parametrize("board", ["penguinpi", "icoboard"])
async def test_late_replies_are_counted_late_and_never_used(make_robot, board) -> None:
    robot = make_robot(ICO_V2 if board == "icoboard" else "")
    async with robot.node() as node:
        _sim, hw = await start_stack(robot, node)
        wheels = node.subscribe(keys.WHEELS, latest=False, maxsize=10_000)
        sender = Sender(node, "late")
        pub = node.publisher(keys.WHEELS_CMD)
        for _ in range(10):
            pub.put(m.WheelSpeeds(**sender.fields(left=0.1, right=0.1)))
            await asyncio.sleep(0.05)
        before = await loop_stats(node)
        # The board answers late, past the timeout (PenguinPi 20 ms; icoBoard half a period).
        late_s = 0.03 if board == "penguinpi" else 0.002
        for _ in range(15):
            pub.put(m.WheelSpeeds(**sender.fields(left=0.1, right=0.1)))
            await sim_state(node, "delay_replies", seconds=late_s, count=1)
            await asyncio.sleep(0.1)
        await asyncio.sleep(1.2)
        after = await loop_stats(node)
        truth = await sim_state(node)
        assert after.late - before.late >= 10, after
        assert after.unmatched == before.unmatched, after
        # The counts hwbridge reported never went back and never ran ahead of the board's.
        samples = []
        while wheels.pending():
            samples.append(await anext(wheels))
        ticks = [w.ticks_left for w in samples]
        assert ticks == sorted(ticks) and ticks[-1] <= truth.ticks_left + 1
        assert hw.alive()
