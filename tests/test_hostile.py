"""Hostile input: bad payloads on every key and queryable, fuzzed HTTP, against real processes.

The payloads and requests come from ``bench/hostile_input.py`` (the harness that measures memory
with ten times as many). What is checked: nothing crashes, nothing moves (the simulator's truth),
each refusal is a short line and the lines stay few (on the bus and in the output), and good
commands work right after.
"""

from __future__ import annotations

import asyncio
import sys
import time
from collections import Counter
from pathlib import Path

import pytest
from conftest import ROOT, Robot, free_port

sys.path.insert(0, str(ROOT / "bench"))
import hostile_input as hostile  # the bench script is the harness

from icefloe.runtime import BUS_LOG_BURST, BUS_LOG_RATE
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m
from icefloe.services.webapi.server import KEEPALIVE_S


async def wait_listening(port: int, proc, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while True:
        assert proc.alive(), proc.output
        try:
            _, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.close()
            return
        except OSError:
            assert time.monotonic() < deadline, f"webapi does not listen on {port}:\n{proc.output}"
            await asyncio.sleep(0.1)


MALFORMED = {
    "over-long URL": b"GET /robot/set/velocity?value=" + b"1" * 20_000 + b" HTTP/1.1\r\nHost: r\r\n\r\n",
    "over-long header": b"GET /hat/dip/get HTTP/1.1\r\nHost: r\r\nX-A: " + b"a" * 20_000 + b"\r\n\r\n",
    "too many headers": b"GET /hat/dip/get HTTP/1.1\r\n" + b"".join(b"X-%d: 1\r\n" % i for i in range(300)) + b"\r\n",
    "bad method": b"G\xffT /robot/stop HTTP/1.1\r\nHost: r\r\n\r\n",
    "garbage": bytes(range(256)) * 4,
    "TLS hello": b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03" + b"\x00" * 64,
    "bad version": b"GET /robot/stop HTTX/1.1\r\nHost: r\r\n\r\n",
    "bad header bytes": b"GET /hat/dip/get HTTP/1.1\r\nHost\xff: r\r\n\r\n",
    "bad body length": b"POST /robot/stop HTTP/1.1\r\nHost: r\r\nContent-Length: -1\r\n\r\n",
    "null byte": b"GET /robot/stop\x00 HTTP/1.1\r\nHost: r\r\n\r\n",
}


async def test_malformed_http_gets_a_400_and_one_short_line(make_robot) -> None:
    robot: Robot = make_robot(f'[webapi]\nhost = "127.0.0.1"\nport = {free_port()}\n')
    port = robot.config.webapi.port
    web = robot.start("webapi")
    await wait_listening(port, web)
    for what, data in MALFORMED.items():
        status = await hostile.one_request("127.0.0.1", port, data, timeout=10.0)
        assert status == "400", (what, status, web.output)
        await asyncio.sleep(0.4)  # a few a second: each one gets its line
    lines = [line for line in web.output.splitlines() if "bad HTTP request" in line]
    assert len(lines) == len(MALFORMED), web.output
    assert all(len(line) < 200 for line in lines), lines  # with the time stamp, level and logger name
    assert "Traceback" not in web.output and "Error handling request" not in web.output
    # A flood of them: still 400 each, and a few lines a second.
    before = len(web.output.splitlines())
    start = time.monotonic()
    answers = await asyncio.gather(*(hostile.one_request("127.0.0.1", port, MALFORMED["over-long URL"], 20.0)
                                     for _ in range(300)))
    took = time.monotonic() - start
    assert Counter(answers) == {"400": 300}
    await asyncio.sleep(1.5)  # the count of what was not shown comes at the end of its second
    new = web.output.splitlines()[before:]
    assert len(new) <= 7 * (took + 2), new
    assert any("more lines like these not shown" in line and "bad HTTP request" in line for line in new), new
    assert "Traceback" not in web.output
    # And a good request is served as before.
    assert await hostile.one_request("127.0.0.1", port, b"GET /hat/button/get HTTP/1.1\r\nHost: r\r\n"
                                     b"Connection: close\r\n\r\n", 10.0) == "200"
    assert web.stop() == 0


IDLE = 50
"""Keep-alive connections left open by the whole-stack test, to be closed by webapi."""


async def http_phase(port: int) -> tuple[Counter[tuple[str, str, str]], int]:
    """5,000 fuzzed requests, and how many of `IDLE` idle connections webapi closed meanwhile."""
    idle = await hostile.open_idle("127.0.0.1", port, IDLE)
    answers = await hostile.fuzz_http("127.0.0.1", port, 5_000, seed=2)
    return answers, await hostile.closed_by_server(idle, KEEPALIVE_S + 10.0)


@pytest.mark.slow
def test_the_whole_stack_takes_hostile_input_and_then_drives(tmp_path: Path) -> None:
    stack = hostile.Stack(tmp_path)
    name = stack.config.name
    stack.start()
    try:
        session = stack.session()
        try:
            stack.wait_alive(session, timeout=120.0)
            counter = hostile.LogCounter(session, name)
            begin = hostile.truth(session, name)
            lines_before = hostile.output_lines(stack.output())
            rss_before = stack.rss()
            start = time.monotonic()
            sent = hostile.flood(session, name, 10_000, seed=1, rate_hz=5_000.0)
            answers, closed = asyncio.run(http_phase(stack.web_port))
            time.sleep(2.0)  # the counts of lines not shown come at the end of their second
            took = time.monotonic() - start
            end = hostile.truth(session, name)
            rss_after = stack.rss()
            on_bus, output = counter.take(), hostile.output_lines(stack.output()) - lines_before
            text = stack.output()

            # Every input was hit; nothing crashed or restarted; nothing moved.
            assert {t.name for t in (*hostile.READ_KEYS, *hostile.QUERYABLES)} <= set(sent)
            assert "exited with code" not in text and "Traceback" not in text, text[-5000:]
            assert hostile.moved(begin, end) < 0.001 and (end.duty_left, end.duty_right) == (0.0, 0.0)
            # Memory: every process within the bench's bound of where it started (docs/hostile-input.md).
            grew = {p: round(rss_after.get(p, 0.0) - v, 1) for p, v in rss_before.items()}
            assert max(grew.values()) <= hostile.BOUND_MIB and min(rss_after.values()) > 0, grew
            # Few lines: each process writes at most 7 lines a second per LimitedLog (hwbridge,
            # odometry and the localizer have two), and copies at most 20 a second to the bus.
            for service in hostile.STACK:
                assert output[service] <= 14 * (took + 1) + 10, (service, output[service], took)
                assert on_bus[service] <= BUS_LOG_BURST + BUS_LOG_RATE * took, (service, on_bus[service], took)
            # HTTP: refused (4xx), except on routes that read or set LEDs; never an error of ours.
            statuses = Counter(status for (_, _, status) in answers.elements())
            assert set(statuses) <= {"200", "400", "404", "405"}, statuses
            assert {route for (_, route, status) in answers if status == "200"} <= hostile.HARMLESS
            assert closed == IDLE, "idle keep-alive connections are closed by the server"

            # Good commands work right after: drive on the bus, stop, a query, HTTP.
            twist = keys.key(name, keys.TWIST)
            for _ in range(10):
                session.put(twist, codec.encode(m.Twist(v=0.1, w=0.0)), encoding=codec.MSGPACK)
                time.sleep(0.1)
            session.put(keys.key(name, keys.STOP), b"", encoding=codec.MSGPACK)
            time.sleep(1.0)
            driven = hostile.truth(session, name)
            assert hostile.moved(end, driven) > 0.02  # (how a stop stops is tests/test_hwbridge_*'s subject)
            info = [r.ok for r in session.get(keys.key(name, keys.INFO), timeout=10.0) if r.ok is not None]
            assert len(info) == 1
            request = b"GET /robot/set/velocity?value=20,20&time=0.5 HTTP/1.1\r\nHost: r\r\nConnection: close\r\n\r\n"
            assert asyncio.run(hostile.one_request("127.0.0.1", stack.web_port, request, 20.0)) == "200"
            assert hostile.moved(driven, hostile.truth(session, name)) > 0.005
            counter.close()
        finally:
            session.close()
    finally:
        assert stack.stop() == 0, stack.output()[-5000:]
