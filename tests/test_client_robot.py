"""`icefloe.client.Robot` / `AsyncRobot` against a stand-in robot on a real bus (`Board`).

The blocking `Robot` is called through ``asyncio.to_thread`` here only because the
stand-in robot lives on this test's event loop; a student's script just calls it.
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
import time

import numpy as np
import pytest
from conftest import flooding, free_port
from webapi_helpers import board, jpeg, wait_for

from icefloe import client
from icefloe.client import AsyncRobot, Encoders, Robot
from icefloe.errors import NotReachable
from icefloe.schemas import keys
from icefloe.schemas import messages as m


async def test_blocking_robot_reads_state_and_drives(robot):
    async with board(robot) as b:
        b.ticks = [384, -10]
        b.pose = m.Pose(stamp=0, x=0.25, y=-0.5, theta=math.pi / 2)
        b.battery = m.BatteryReading(stamp=0, voltage=7.5, current=0.25)
        b.image = jpeg(shade=0)
        endpoint = robot.config.zenoh.connect[0]
        r = await asyncio.to_thread(Robot, robot.name, connect=endpoint)
        try:
            pose = await asyncio.to_thread(lambda: r.pose)
            assert (pose.x, pose.y, pose.theta) == (0.25, -0.5, math.pi / 2)
            assert await asyncio.to_thread(lambda: r.encoders) == Encoders(384, -10)
            assert (await asyncio.to_thread(lambda: r.battery)).voltage == 7.5
            frame = await asyncio.to_thread(r.image)
            assert isinstance(frame, np.ndarray) and frame.shape == (240, 320, 3)
            assert f"<Robot '{robot.name}' at {endpoint}: pose x=0.250 m y=-0.500 m θ=90.0°" in repr(r)
            assert "encoders L=384 R=-10, battery 7.50 V>" in repr(r)

            await asyncio.to_thread(r.set_velocity, 0.1, 0.2)  # holds until stop
            await wait_for(lambda: len(b.wheels) >= 3)
            assert (b.wheels[-1].left, b.wheels[-1].right) == (0.1, 0.2)
            await asyncio.to_thread(r.stop)  # returns once "hwbridge" confirmed it
            await wait_for(lambda: len(b.stops) == 1)
            # One sender, numbered in the order issued, the stop after every held command.
            sender = b.stops[0].sender
            assert sender and {w.sender for w in b.wheels} == {sender}
            seqs = [w.seq for w in b.wheels]
            assert seqs == sorted(seqs) and b.stops[0].seq > seqs[-1]
            assert (b.halts[0].sender, b.halts[0].seq, b.halts[0].rest) == (sender, b.stops[0].seq, False)
            count = len(b.wheels)
            await asyncio.sleep(0.5)
            assert len(b.wheels) == count, "the held velocity went on after stop()"

            done = await asyncio.to_thread(r.set_velocity, 0.1, 0.1, 0.4, 0.1)
            assert isinstance(done, m.MotionDone) and done.completed
            assert [(x.left, x.right, x.duration, x.accel) for x in b.motions] == [(0.1, 0.1, 0.4, 0.1)]

            reset = await asyncio.to_thread(r.reset_pose, 1.0, 2.0, 0.5)
            assert (reset.x, reset.y, reset.theta) == (1.0, 2.0, 0.5)
            await wait_for(lambda: r.pose.x == 1.0)

            seen: list[m.Pose] = []
            cancel = r.on_pose(seen.append)
            await wait_for(lambda: len(seen) >= 2)
            cancel()
            assert seen[-1].x == 1.0

            await asyncio.to_thread(r.set_velocity, 0.05, 0.05)
            await wait_for(lambda: b.wheels[-1].left == 0.05)
        finally:
            await asyncio.to_thread(r.close)
        # close() stops the wheels this program set moving.
        await wait_for(lambda: len(b.stops) == 2)


async def test_leds_and_screen_text(robot):
    async with board(robot) as b, AsyncRobot(config=robot.config) as r:
        r.leds[2] = True
        r.leds.pulse(3, 0.1)
        await r.print_oled("hello\nworld")
        await wait_for(lambda: b.raw.count("io/leds") == 2 and "oled/text" in b.raw)
        assert r.leds[2] is True and r.leds[4] is False
        with pytest.raises(ValueError, match=r"led: expected 1 \(red\) or 2\.\.4"):
            r.leds[7] = True
        with pytest.raises(ValueError, match=r"seconds: must be in \(0, 0.255\]"):
            r.leds.pulse(2, 1.0)


async def test_bad_arguments_name_the_argument_and_send_nothing(robot):
    async with board(robot) as b, AsyncRobot(config=robot.config) as r:
        await asyncio.sleep(0.2)
        cases = [
            (dict(left="fast", right=0.1), "left: expected a number, got 'fast'"),
            (dict(left=0.1, right=math.nan), "right: must be a finite number, got nan"),
            (dict(left=0.1, right=0.1, duration=-1), "duration: must be > 0 s, got -1"),
            (dict(left=0.1, right=0.1, duration=1, accel=0.5), r"accel: each ramp \(0.5 s\)"),
            (dict(left=0.1, right=0.1, duration=1, accel=-1), "accel: must be >= 0 s"),
            (dict(left=0.1, right=0.1, accel=0.2), "accel: only with a duration"),
            (dict(left=True, right=0.1), "left: expected a number, got True"),
        ]
        for kwargs, message in cases:
            with pytest.raises(ValueError, match=message):
                await r.set_velocity(**kwargs)
        with pytest.raises(ValueError, match="theta: expected a number"):
            await r.reset_pose(theta="north")
        await r.stop()  # a message after the bad calls: when it arrives, the others would have
        await wait_for(lambda: "cmd/stop" in b.raw)
        assert b.raw == ["cmd/stop"]
    with pytest.raises(ValueError, match="name: 'a/b' is not a robot name"):
        AsyncRobot("a/b")
    with pytest.raises(ValueError, match="connect: 'localhost' is not a Zenoh endpoint"):
        AsyncRobot("x", connect="localhost")


async def test_unreachable_robot_names_the_endpoint():
    endpoint = f"tcp/127.0.0.1:{free_port()}"  # nobody listens there
    with pytest.raises(NotReachable, match=f"robot 'penguin9': no Zenoh router answers at {endpoint}"):
        await asyncio.to_thread(Robot, "penguin9", connect=endpoint, timeout=0.5)


async def test_missing_service_names_the_key(robot):
    r = await asyncio.to_thread(Robot, config=robot.config, timeout=0.5)
    try:
        with pytest.raises(NotReachable, match=f"nothing on icefloe/{robot.name}/odom/pose within"):
            await asyncio.to_thread(lambda: r.pose)
        with pytest.raises(NotReachable, match=f"icefloe/{robot.name}/cmd/motion: nobody answers"):
            await asyncio.to_thread(r.set_velocity, 0.1, 0.1, 0.2)
        assert repr(r).endswith(": no data yet>")
    finally:
        await asyncio.to_thread(r.close)


async def test_async_robot_sees_the_bus(robot):
    async with board(robot) as b, AsyncRobot(config=robot.config) as r:
        b.pose = m.Pose(stamp=0, x=0.1, y=0.0, theta=0.0)
        await r.ready(keys.ODOM_POSE.name, keys.WHEELS.name)
        assert r.pose is not None and r.pose.x == 0.1
        assert r.encoders == Encoders(0, 0)
        assert r.battery is None  # nothing published: None, not a wait
        got: list[float] = []

        async def on_pose(p: m.Pose) -> None:
            got.append(p.x)

        r.on_pose(on_pose)
        await wait_for(lambda: len(got) >= 2)


async def test_hostile_button_messages_cost_a_bounded_number_of_calls(robot):
    """A flood, absurd counts, unknown buttons, garbage: the client stays bounded and keeps going."""
    async with robot.node("board") as node, AsyncRobot(config=robot.config) as r:
        calls: list[int] = []
        r.buttons["S4"].when_pressed = lambda b: calls.append(b.number)
        with pytest.raises(ValueError, match=r"must take no argument, or one \(the button\)"):
            r.buttons["S4"].when_pressed = lambda a, b: None
        with pytest.raises(ValueError, match="button: expected one of S1, S2, S3, S4, SDN"):
            r.buttons["S9"]
        pub = node.publisher(keys.BUTTONS)
        await asyncio.sleep(0.5)  # the client's subscriber is known to the router
        pub.put(m.Buttons(stamp=0, button=3, presses=1_000_000))  # one message, a million presses
        pub.put(m.Buttons(stamp=0, button=3, presses=-5))
        pub.put(m.Buttons(stamp=0, button=77))
        pub.put(m.Buttons(stamp=0, button=3, event="release"))  # S4 cannot tell releases: ignored
        node.session.put(node.key(keys.BUTTONS), b"\x93garbage")
        pub.put(m.Buttons(stamp=0, button=3))
        await wait_for(lambda: len(calls) == 17)
        await asyncio.sleep(0.3)
        assert len(calls) == 17  # 16 for the million, 1 for the last press
        assert r.buttons["S4"].presses == 1_000_001 and r.buttons["S4"].is_pressed is None
        with pytest.raises(ValueError, match=r"blink: one number of seconds, or two \(lit, dark\)"):
            await r.led(2, blink=(0.1,))
        with pytest.raises(ValueError, match="times: expected a whole number >= 1"):
            await r.led(2, blink=0.1, times=0)


async def test_a_slow_callback_on_the_blocking_robot_drops_events_not_memory(robot, monkeypatch, caplog):
    monkeypatch.setattr(client, "MAX_PENDING_CALLS", 3)
    async with board(robot) as b:
        b.pose = m.Pose(stamp=0, x=0.5, y=0.0, theta=0.0)
        r = await asyncio.to_thread(Robot, config=robot.config)
        try:
            threads: list[str] = []

            def slow(_pose: m.Pose) -> None:
                threads.append(threading.current_thread().name)
                time.sleep(0.3)

            with caplog.at_level(logging.WARNING, logger="icefloe.client"):
                r.on_pose(slow)
                await asyncio.sleep(1.5)  # 30 poses for a callback that takes 5
                assert r._pending.get(slow, 0) <= 3
            assert any("events behind: newer ones dropped" in rec.getMessage() for rec in caplog.records)
            assert threads and set(threads) == {"icefloe-callbacks_0"}
            assert (await asyncio.to_thread(lambda: r.pose)).x == 0.5  # state still comes in
        finally:
            await asyncio.to_thread(r.close)


async def test_a_bad_argument_to_the_blocking_robot_sends_nothing_not_even_a_stop(robot):
    async with board(robot) as b:
        r = await asyncio.to_thread(Robot, config=robot.config)
        try:
            with pytest.raises(ValueError, match=r"left: 5\.0 m/s is beyond this robot's max_wheel_speed"):
                await asyncio.to_thread(r.set_velocity, 5, 5, 1)
            with pytest.raises(ValueError, match="distance: expected a number"):
                await asyncio.to_thread(r.forward, "far")
            await asyncio.sleep(0.5)
            assert b.raw == []
        finally:
            await asyncio.to_thread(r.close)


EXIT_SCRIPT = """
import sys, time
from icefloe import Robot
with Robot(config=sys.argv[1]) as robot:
    time.sleep(0.3)  # the stream is flowing into the robot's subscriptions
print("closed")
"""


async def test_a_program_exits_cleanly_while_the_bus_streams_to_it(robot, tmp_path):
    """The blocking `Robot` runs its loop on a daemon thread; the threads that hand it samples
    must be done before the interpreter exits, or the process aborts ("FATAL: exception not
    rethrown", exit -6) on its last line: seen in CI with docs/first-hour.md's hello.py."""
    import subprocess
    import sys

    script = tmp_path / "exit.py"
    script.write_text(EXIT_SCRIPT)
    async with flooding(robot):
        for _ in range(8):
            done = await asyncio.to_thread(subprocess.run, [sys.executable, str(script), str(robot.config_path)],
                                           capture_output=True, text=True, timeout=60)
            assert (done.returncode, done.stdout.strip()) == (0, "closed"), done.stderr[-3000:]
            assert "FATAL" not in done.stderr, done.stderr[-3000:]
