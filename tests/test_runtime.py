"""The runtime over real Zenoh sessions: a router process and two sessions in this process."""

from __future__ import annotations

import asyncio
import logging
import math
import time

import msgspec
import pytest
from conftest import Robot, flooding, wait_for

from icefloe.errors import NotReachable
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m


async def next_of(sub, timeout: float = 5.0):
    return await asyncio.wait_for(sub.__anext__(), timeout)


async def settle() -> None:
    """Let the router propagate new declarations before the first put."""
    await asyncio.sleep(0.3)


async def test_typed_publish_and_subscribe(robot: Robot) -> None:
    async with robot.node("a") as a, robot.node("b") as b:
        sub = b.subscribe(keys.ODOM_POSE, latest=False)
        pub = a.publisher(keys.ODOM_POSE)
        await settle()
        pub.put(m.Pose(stamp=1, x=1.0, y=2.0, theta=0.5))
        got = await next_of(sub)
        assert got == m.Pose(stamp=1, x=1.0, y=2.0, theta=0.5)
        with pytest.raises(TypeError, match="carries Pose, not Twist"):
            pub.put(m.Twist(v=0.0, w=0.0))


async def test_commands_are_fifo_and_state_is_latest(robot: Robot) -> None:
    async with robot.node("a") as a, robot.node("b") as b:
        fifo = b.subscribe(keys.TWIST)  # an "in" key: FIFO by default
        latest = b.subscribe(keys.ODOM_POSE)  # an "out" key: latest value by default
        twist, pose = a.publisher(keys.TWIST), a.publisher(keys.ODOM_POSE)
        await settle()
        for i in range(20):
            twist.put(m.Twist(v=i / 100, w=0.0))
            pose.put(m.Pose(stamp=i, x=float(i), y=0.0, theta=0.0))
        await wait_for(lambda: fifo.pending() == 20 and latest.skipped >= 1, timeout=5)
        assert [(await next_of(fifo)).v for _ in range(20)] == [i / 100 for i in range(20)]
        assert (await next_of(latest)).stamp == 19
        assert latest.pending() == 0


async def test_bad_payloads_are_dropped_with_one_line_naming_key_and_field(
    robot: Robot, caplog: pytest.LogCaptureFixture
) -> None:
    key = keys.key(robot.name, keys.TWIST)
    bad = [
        (msgspec.msgpack.encode({"v": "fast", "w": 0.0}), codec.MSGPACK, "$.v"),
        (codec.encode(m.Twist(v=1.0, w=2.0))[:-3], codec.MSGPACK, "truncated"),
        (b'{"v": 0.1}', codec.JSON, "missing required field `w`"),
        (b'{"v": 0.1, "w": 0, "speed": 3}', codec.JSON, "unknown field `speed`"),
        (msgspec.msgpack.encode({"v": math.nan, "w": 0.0}), codec.MSGPACK, "`v` must be a finite"),
        (b'{"v": 0.1, "w": 0}', "text/csv", "unknown encoding 'text/csv'"),
    ]
    caplog.set_level(logging.WARNING, logger="icefloe.victim")
    async with robot.node("sender") as sender, robot.node("victim") as victim, robot.node("reader") as reader:
        victim.limited.burst = len(bad)  # here every line counts (a flood: the next test)
        bus_log = reader.subscribe(keys.LOG, latest=False)
        sub = victim.subscribe(keys.TWIST)
        await settle()
        for payload, encoding, _ in bad:
            sender.session.put(key, payload, encoding=encoding)
        sender.session.put(key, b'{"v": 0.25, "w": 0}', encoding=codec.JSON)
        assert await next_of(sub) == m.Twist(v=0.25, w=0.0)  # still running, the good one got through
        assert sub.rejected == len(bad)
        lines = [r.getMessage() for r in caplog.records if r.name == "icefloe.victim"]
        assert len(lines) == len(bad)
        for line, (_, _, names) in zip(lines, bad, strict=True):
            assert key in line and names in line, line
        # The same lines are on the bus key `log`, from the service that dropped them.
        on_bus = [await next_of(bus_log) for _ in bad]
        assert all(entry.service == "victim" and entry.level == "warning" for entry in on_bus)
        assert [e.text for e in on_bus] == lines


async def test_a_flood_of_bad_payloads_is_a_few_lines_and_a_count(
    robot: Robot, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="icefloe.victim")
    async with robot.node("sender") as sender, robot.node("victim") as victim, robot.node("reader") as reader:
        bus_log = reader.subscribe(keys.LOG, latest=False, maxsize=10_000)
        sub = victim.subscribe(keys.TWIST, maxsize=10_000)
        await settle()
        key = keys.key(robot.name, keys.TWIST)
        for i in range(1000):
            sender.session.put(key, b'{"v": "fast%d"}' % i, encoding=codec.JSON)
        sender.session.put(key, b'{"v": 0.25, "w": 0}', encoding=codec.JSON)
        assert await next_of(sub, 30.0) == m.Twist(v=0.25, w=0.0)
        lines = [r.getMessage() for r in caplog.records if r.name == "icefloe.victim"]
        assert len(lines) == victim.limited.burst == 3
        await wait_for(lambda: sub.rejected == 1000, timeout=30)
        await wait_for(lambda: len(caplog.records) > 3, timeout=5)  # when the period is over
        count = caplog.records[3].getMessage()
        assert count.startswith("997 more lines like these not shown in 1.") and count.endswith(" s: 997 cmd/twist")
        on_bus = [(await next_of(bus_log)).text for _ in range(4)]
        assert on_bus == [*lines, count]
        await asyncio.sleep(0.3)
        assert bus_log.pending() == 0


async def test_the_bus_copy_of_a_log_is_limited(robot: Robot) -> None:
    from icefloe.runtime import BUS_LOG_BURST, BUS_LOG_RATE

    async with robot.node("chatty") as chatty, robot.node("reader") as reader:
        bus_log = reader.subscribe(keys.LOG, latest=False, maxsize=10_000)
        await settle()
        start = time.monotonic()
        for i in range(5000):  # a service logging without a limit (say, a bug in a loop)
            chatty.log.warning("line %d", i)
        took = time.monotonic() - start
        await asyncio.sleep(1.0)
        got = [(await next_of(bus_log)).text for _ in range(bus_log.pending())]
        assert BUS_LOG_BURST <= len(got) <= BUS_LOG_BURST + BUS_LOG_RATE * (took + 0.1), (len(got), took)
        assert got[:3] == ["line 0", "line 1", "line 2"]
        await asyncio.sleep(0.2)
        chatty.log.warning("after")
        last = (await next_of(bus_log)).text
        assert last.startswith("after [") and last.endswith("lines before this one not copied to the bus]")


async def test_a_flood_of_queries_is_answered_busy_beyond_the_limit(robot: Robot) -> None:
    from icefloe.runtime import MAX_QUERIES

    release = asyncio.Event()
    running = 0
    most = 0

    async def slow(_request: m.Stop) -> m.RobotInfo:
        nonlocal running, most
        running += 1
        most = max(most, running)
        await release.wait()
        running -= 1
        return m.RobotInfo(name="x", board="penguinpi", backend="sim", wheel_diameter=0.065, track=0.156,
                           ticks_per_rev=384, max_wheel_speed=0.5)

    async with robot.node("server") as server, robot.node("client") as client:
        server.queryable(keys.INFO, slow)
        await settle()
        answers: list[str] = []

        def on_reply(reply) -> None:
            answers.append("ok" if reply.ok is not None else reply.err.payload.to_string())

        for _ in range(200):
            client.session.get(client.key(keys.INFO), on_reply, timeout=20.0)
        # The refusals can come back before the accepted handlers have had their first turn.
        await wait_for(lambda: len(answers) >= 200 - MAX_QUERIES and running == MAX_QUERIES, timeout=20)
        assert most == MAX_QUERIES and len(answers) == 200 - MAX_QUERIES
        release.set()
        await wait_for(lambda: len(answers) == 200, timeout=20)
        assert answers.count("ok") == MAX_QUERIES
        assert all("busy" in a for a in answers if a != "ok")
        assert (await client.query(keys.INFO)).name == "x"  # and the next one is served


async def test_queryable_answers_and_rejects_bad_requests(robot: Robot) -> None:
    async def reset(request: m.PoseReset) -> m.Pose:
        return m.Pose(stamp=7, x=request.x, y=request.y, theta=request.theta)

    async with robot.node("server") as server, robot.node("client") as client:
        server.queryable(keys.ODOM_RESET, reset)
        await settle()
        assert (await client.query(keys.ODOM_RESET, m.PoseReset(x=1.5))).x == 1.5
        assert (await client.query(keys.ODOM_RESET)).x == 0.0  # an empty request is the default
        # A request with a field the message does not have gets an error reply naming it.
        errors = await asyncio.to_thread(_errors_of, client, b'{"z": 1}')
        assert len(errors) == 1 and "unknown field `z`" in errors[0]


def _errors_of(client, payload: bytes) -> list[str]:
    replies = client.session.get(client.key(keys.ODOM_RESET), payload=payload, encoding=codec.JSON, timeout=2.0)
    return [r.err.payload.to_string() for r in replies if r.err is not None]


async def test_liveliness_lists_services_and_forgets_closed_ones(robot: Robot) -> None:
    async with robot.node("watcher") as watcher:
        async with robot.node("odometry"):
            await settle()
            alive = await watcher.alive()
            assert keys.alive_key(robot.name, "odometry") in alive
            assert keys.alive_key(robot.name, "watcher") in alive
        await asyncio.sleep(0.3)
        assert keys.alive_key(robot.name, "odometry") not in await watcher.alive()


async def test_no_router_fails_fast_when_asked_to(make_robot) -> None:
    from conftest import free_port

    from icefloe.runtime import Node

    robot = make_robot()
    cfg = msgspec.structs.replace(
        robot.config, zenoh=msgspec.structs.replace(robot.config.zenoh, connect=[f"tcp/127.0.0.1:{free_port()}"])
    )
    with pytest.raises(NotReachable, match=r"cannot reach a Zenoh router at tcp/127\.0\.0\.1:"):
        async with Node("cli", cfg, retry=False):
            pass


async def test_batches_deliver_everything_in_order_once_per_period(robot: Robot) -> None:
    async with robot.node("a") as a, robot.node("b") as b:
        batches = b.batches(keys.WHEELS, 0.05, maxsize=1000)
        pub = a.publisher(keys.WHEELS)
        await settle()
        assert await asyncio.wait_for(anext(batches), 1.0) == []  # nothing came: an empty list

        def wheels(i: int) -> m.Wheels:
            return m.Wheels(stamp=i, ticks_left=i, ticks_right=-i, speed_left=0.0, speed_right=0.0)

        for i in range(300):
            pub.put(wheels(i))
        got: list[int] = []
        sizes: list[int] = []
        while len(got) < 300:
            batch = await asyncio.wait_for(anext(batches), 1.0)
            sizes.append(len(batch))
            got += [w.stamp for w in batch]
        assert got == list(range(300))
        assert sizes[0] > 1, "samples that arrive within a period come together"
        a.session.put(a.key(keys.WHEELS), b'{"stamp": "late"}', encoding=codec.JSON)
        pub.put(wheels(300))
        got = []
        while not got:
            got = [w.stamp for w in await asyncio.wait_for(anext(batches), 1.0)]
        assert got == [300] and batches.rejected == 1  # the bad one was dropped, the reader carried on


def test_a_reader_thread_survives_a_failing_delivery_with_a_few_lines(caplog: pytest.LogCaptureFixture) -> None:
    """A delivery that raises (a bug) on every sample: the reader goes on to the next one, and a
    thousand failures are a few log lines, not a thousand tracebacks."""
    from icefloe.logs import LimitedLog
    from icefloe.runtime import deliver_on_thread

    delivered: list[int] = []

    def deliver(sample: int) -> None:
        delivered.append(sample)
        raise ValueError(f"bug on sample {sample}")

    log = logging.getLogger("icefloe.test.reader")
    with caplog.at_level(logging.WARNING, logger=log.name):
        # Zenoh's channel is an iterator that ends when its subscriber is undeclared: a list does the same.
        reader = deliver_on_thread(iter(range(1000)), deliver, "icefloe test/key", LimitedLog(log))
        reader.join(30)  # a loaded machine may take its time; it ends with the channel
    assert delivered == list(range(1000))
    lines = [r for r in caplog.records if r.name == log.name]
    assert 1 <= len(lines) <= 10 and "delivering a sample failed" in lines[0].getMessage()


async def test_latest_gives_the_newest_message_when_asked(robot: Robot) -> None:
    """`Node.latest`: no Python per sample; `get` decodes the newest only, keeps it until a newer
    one comes, and drops a bad payload or a wildcard put with a count (the old value stays)."""
    async with robot.node("a") as a, robot.node("b") as b:
        latest = b.latest(keys.ODOM_POSE)
        pub = a.publisher(keys.ODOM_POSE)
        await settle()
        assert latest.get() is None
        for i in range(50):
            pub.put(m.Pose(stamp=i, x=float(i), y=0.0, theta=0.0))
        await wait_for(lambda: (p := latest.get()) is not None and p.stamp == 49, timeout=10)
        assert latest.get().stamp == 49  # nothing newer: the same message again
        a.session.put(b.key(keys.ODOM_POSE), b"\x81\xa1x\xa4fast", encoding=codec.MSGPACK)
        await wait_for(lambda: latest.get() is not None and latest.rejected == 1, timeout=10)
        a.session.put(keys.key("*", keys.ODOM_POSE), codec.encode(m.Pose(stamp=99, x=9.0, y=0.0, theta=0.0)),
                      encoding=codec.MSGPACK)
        await wait_for(lambda: latest.get() is not None and latest.rejected == 2, timeout=10)
        assert latest.value.stamp == 49


SERVICE_SCRIPT = """
import sys
from icefloe.runtime import Node, run
from icefloe.schemas import keys

async def main(config):
    async with Node("reader", config) as node:
        poses, wheels = node.subscribe(keys.ODOM_POSE, latest=False), node.subscribe(keys.WHEELS)
        async for _ in poses:
            print("receiving", flush=True)
            break
        async for _ in wheels:
            pass

run(main)
"""


async def test_a_service_ends_cleanly_on_sigint_while_samples_stream_in(robot: Robot, tmp_path) -> None:
    """SIGINT while its reader threads hand it samples as fast as they come: the service exits 0,
    with no traceback and no abort ("FATAL: exception not rethrown", exit -6)."""
    import signal
    import subprocess
    import sys

    script = tmp_path / "service.py"
    script.write_text(SERVICE_SCRIPT)
    async with flooding(robot):
        for _ in range(3):
            proc = subprocess.Popen([sys.executable, str(script), "--config", str(robot.config_path)],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            try:
                line = await asyncio.wait_for(asyncio.to_thread(proc.stdout.readline), 60)
                assert line.strip() == "receiving", proc.stderr.read()[-3000:] if proc.poll() is not None else line
                proc.send_signal(signal.SIGINT)
                _, err = await asyncio.to_thread(proc.communicate, timeout=60)
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
            assert proc.returncode == 0, err[-3000:]
            assert "FATAL" not in err and "Traceback" not in err, err[-3000:]


def _wake_storm(loop: asyncio.AbstractEventLoop, count: int = 20_000) -> tuple[list[int], int]:
    """A thread queues ``count`` items as fast as it can, signalling a `LoopWakeup` after each;
    the loop takes them, waiting for a wake-up whenever the queue is empty. A lost wake-up hangs
    the loop (the wait times out). Returns what the loop took, and how often it was woken."""
    import threading
    from collections import deque

    from icefloe.runtime import LoopWakeup

    async def take() -> tuple[list[int], int]:
        items: deque[int] = deque()
        woken = asyncio.Event()
        calls = 0

        def on_wake() -> None:
            nonlocal calls
            calls += 1
            woken.set()

        wakeup = LoopWakeup(asyncio.get_running_loop(), on_wake)

        def produce() -> None:
            for i in range(count):
                items.append(i)
                wakeup.signal()
                if i % 500 == 0:
                    time.sleep(0.001)  # let the loop catch up and wait now and then

        producer = threading.Thread(target=produce)
        producer.start()
        got: list[int] = []
        try:
            while len(got) < count:
                while items:
                    got.append(items.popleft())
                woken.clear()
                if len(got) < count and not items:
                    await asyncio.wait_for(woken.wait(), 30)
        finally:
            producer.join()
            wakeup.close()
        return got, calls

    return loop.run_until_complete(take())


def test_a_loop_wakeup_misses_no_sample_and_wakes_once_for_many() -> None:
    loop = asyncio.new_event_loop()
    try:
        got, calls = _wake_storm(loop)
    finally:
        loop.close()
    assert got == list(range(20_000))
    assert calls < 20_000, "samples that came while the loop had not looked share a wake-up"


def test_a_loop_wakeup_works_on_a_loop_that_watches_no_descriptors() -> None:
    """Windows' proactor loop has no add_reader: `LoopWakeup` falls back to call_soon_threadsafe."""

    class NoReaders(asyncio.SelectorEventLoop):
        def add_reader(self, *args: object) -> None:
            raise NotImplementedError

    loop = NoReaders()
    try:
        got, _ = _wake_storm(loop, 5_000)
    finally:
        loop.close()
    assert got == list(range(5_000))
