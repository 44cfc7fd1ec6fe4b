"""Hostile input against the whole simulated robot: memory, log lines and motion.

    .venv/bin/python bench/hostile_input.py [--payloads 100000] [--requests 50000] [--burst 4000] [--idle 500]
    .venv/bin/python bench/hostile_input.py --services webapi --payloads 0 --requests 150000 --steps 15

Starts `icefloe up` on the simulated robot (its own port, run dir and web port), waits until
every service is alive, reads each process's RSS, then

1. sends ``--payloads`` bad payloads, mixed over every key a service of the stack reads and every
   queryable it serves (`bad_samples`: garbage bytes, truncated MessagePack, wrong types, unknown
   fields, NaN, bad UTF-8, unknown encodings, deep nesting, 64 KiB blobs, out-of-range values);
2. sends ``--requests`` fuzzed HTTP requests to webapi (`fuzz_requests`: over-long URLs and headers,
   bad methods, garbage bytes, bad encodings, bad bodies, bad parameters), each on its own
   connection, 16 at a time;
3. asks the camera ``--burst`` good queries (snapshots and small frames), 32 at a time: not
   hostile, but a class asking for pictures at once, and what made the camera grow (`query_burst`);
4. leaves ``--idle`` keep-alive connections open and silent until webapi closes them;

and prints the RSS of every process (the router too) at each quarter of each run, the log lines
seen on the bus ``log`` key and in the processes' output, the HTTP status codes, and how far the
simulated robot moved (its truth: it must not move). Nothing sent is a valid motion command.

tests/test_hostile.py runs the same harness with fewer payloads and checks the outcome;
docs/hostile-input.md has the figures.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import msgspec
import zenoh
from common import ROOT, free_port, robot_config
from stack_cpu import children

from icefloe import config as config_mod
from icefloe.config import RobotConfig
from icefloe.errors import BadPayload
from icefloe.runtime import MAX_QUERIES, raw_session
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m

STACK = ("sim", "hwbridge", "odometry", "localizer", "camera", "power", "oled", "webapi", "info")
"""The services of the hostile runs: the default robot without viz."""

READ_KEYS = (keys.TWIST, keys.WHEELS_CMD, keys.STOP, keys.LEDS, keys.LEDARRAY, keys.OLED_TEXT,
             keys.OLED_SCREEN, keys.BOARD_TEXT, keys.BOARD_SCREEN, keys.WHEELS, keys.LOOP,
             keys.HW_BATTERY, keys.BUTTONS, keys.DIP, keys.ODOM_POSE, keys.LANDMARKS, keys.BATTERY,
             keys.LOG, keys.TRUTH, keys.SIM_GPIO)
"""Every key some service of the stack subscribes to: its inputs, whoever is meant to publish them."""

QUERYABLES = (keys.MOTION, keys.HALT, keys.ODOM_RESET, keys.SNAPSHOT, keys.INFO, keys.SHUTDOWN_REQUEST,
              keys.SIM_CONTROL)

OUT_OF_RANGE: dict[str, list[dict]] = {
    # Payloads that decode but that the service must refuse (and say so, rate-limited).
    keys.LEDS.name: [{"led": 99}, {"led": -1, "on": True}, {"led": 2, "pulse": 1e6}],
    keys.LEDARRAY.name: [{"mask": -1}, {"mask": 1 << 40}],
    keys.OLED_SCREEN.name: [{"index": 999}, {"index": -5}],
    keys.BOARD_SCREEN.name: [{"index": 4096}],
    keys.OLED_TEXT.name: [{"text": "x" * 5000}],
    keys.SIM_GPIO.name: [{"stamp": 1, "line": 11, "level": 7}],
    keys.HW_BATTERY.name: [{"stamp": 1, "voltage": -3.0, "current": 0.0}],
    keys.MOTION.name: [{"left": 0.1, "right": 0.1, "duration": -1.0}, {"left": 0.1, "right": 0.1, "duration": 1.0,
                                                                       "accel": 0.6}],
    keys.SIM_CONTROL.name: [{"action": "stall", "wheel": "middle"}, {"action": "drop_bytes", "count": -4}],
}


def _wrong(value: object, rng: random.Random) -> object:
    """A value of another type than ``value``'s (an int would do for a float: not that)."""
    same = {bool: (bool,), int: (int,), float: (float, int), str: (str,)}.get(type(value), ())
    choices = [v for v in ("fast", [1, 2], {"a": 1}, None, True, 1.5, 7, 1 << 63)
               if type(v) not in same and not (isinstance(v, int) and type(value) in (int, float))]
    return rng.choice(choices)


def _example(type_: type[m.Message]) -> dict:
    """A plausible field map for ``type_`` (the values are only templates to spoil)."""
    out: dict[str, object] = {}
    for f in msgspec.structs.fields(type_):
        t = f.type
        out[f.name] = 1.0 if t is float else 1 if t is int else "a" if t is str else True if t is bool else b"" \
            if t is bytes else [] if getattr(t, "__origin__", None) is list else 1
    return out


def bad_samples(robot: str, seed: int) -> Iterator[tuple[str, str, bytes, str]]:
    """Endless ("put" or "get", key, payload, encoding) tuples, each one a payload its service must refuse."""
    rng = random.Random(seed)
    topics = [*READ_KEYS, *QUERYABLES]
    while True:
        topic = rng.choice(topics)
        key = keys.key(robot, topic)
        how = "get" if topic.kind == "query" else "put"
        fields = _example(topic.type)
        kind = rng.randrange(12)
        encoding = codec.MSGPACK
        if kind == 0:  # random bytes
            payload = rng.randbytes(rng.randrange(1, 200))
        elif kind == 1:  # a field of the wrong type
            name = rng.choice(list(fields)) if fields else "x"
            fields[name] = _wrong(fields.get(name), rng)
            payload = msgspec.msgpack.encode(fields)
        elif kind == 2:  # an unknown field, as JSON
            payload, encoding = json.dumps({**fields, "speed": 3}).encode(), codec.JSON
        elif kind == 3:  # truncated MessagePack
            payload = msgspec.msgpack.encode({**fields, "padding": "p" * 20})[: rng.randrange(1, 12)]
        elif kind == 4:  # broken JSON
            payload, encoding = b'{"' + rng.randbytes(rng.randrange(1, 40)), codec.JSON
        elif kind == 5:  # NaN / infinity
            payload = msgspec.msgpack.encode({**fields, **{k: math.nan for k, v in fields.items()
                                                           if isinstance(v, float)}, "x": math.inf})
        elif kind == 6:  # a string that is not UTF-8
            payload = b"\x81\xa4text\xa3\xff\xfe\xfd"
        elif kind == 7:  # an unknown encoding, sometimes a long one (zenoh-python 1.10 panics, in the
            # sender, on one longer than 255 bytes: nobody can send us that)
            encoding = "text/csv" if rng.random() < 0.5 else "x/" + "y" * 250
            payload = msgspec.msgpack.encode(fields)
        elif kind == 8:  # deep nesting
            depth = rng.choice((100, 2000, 20000))
            payload, encoding = b"[" * depth + b"]" * depth, codec.JSON
        elif kind == 9:  # a big blob
            payload = b"\xc1" + rng.randbytes(65536)
        elif kind == 10:  # not a map
            payload = msgspec.msgpack.encode(rng.choice([[1, 2, 3], 7, "stop", None]))
        else:  # out of range, where the type says so; else a missing field or a wrong type
            choices = OUT_OF_RANGE.get(topic.name) or [{"nothing": 0}]
            payload = msgspec.msgpack.encode(rng.choice(choices))
        if kind == 11 or refused(key, payload, encoding):  # kind 11 is refused by the service itself
            yield how, key, payload, encoding


def refused(key: str, payload: bytes, encoding: str) -> bool:
    """Does the key's Struct refuse this payload? (The generator's self-check; range checks excluded.)"""
    topic = keys.topic_of(key)
    assert topic is not None
    try:
        codec.decode(payload, encoding, topic.type, key)
    except BadPayload:
        return True
    return False


# ---------------------------------------------------------------------- bus flood


def flood(session: zenoh.Session, robot: str, count: int, seed: int, rate_hz: float = 10_000.0) -> Counter[str]:
    """Send ``count`` bad samples at up to ``rate_hz`` (puts and queries); the count per key."""
    sent: Counter[str] = Counter()
    samples = bad_samples(robot, seed)
    start = time.monotonic()
    for i in range(count):
        how, key, payload, encoding = next(samples)
        if how == "put":
            session.put(key, payload, encoding=encoding)
        else:
            session.get(key, lambda _reply: None, payload=payload, encoding=encoding, timeout=1.0)
        sent[key.split("/", 2)[2]] += 1
        ahead = (i + 1) / rate_hz - (time.monotonic() - start)
        if ahead > 0.002:
            time.sleep(ahead)
    return sent


# ---------------------------------------------------------------------- HTTP fuzz

ROUTES = ("/robot/set/velocity", "/robot/get/encoder", "/motor/set/velocity", "/motor/get/encoder",
          "/hat/ledarray/set", "/hat/screen/set", "/hat/screen/print", "/led/set/state", "/led/set/count",
          "/battery/get/voltage", "/hat/dip/get")

BAD_PARAMS = ("value=abc", "value=1e999", "value=nan,nan", "value=50", "value=1000,1000", "value=50,50&time=-1",
              "value=50,50&time=0", "value=50,50&time=1&accel=9", "value=50,50&accel=1", "id=9&value=1",
              "id=0&value=5000", "value=0x1ffff", "value=%ff%fe", "value=%zz", "id=1&value=0.5",
              "value=" + "9" * 400, "value=50,50&time=1e999")
"""Parameters a motion route refuses (`HARMLESS` routes may take some of them)."""


HARMLESS = frozenset(("/robot/get/encoder", "/motor/get/encoder", "/battery/get/voltage", "/hat/dip/get",
                      "/hat/screen/print", "/hat/screen/set", "/hat/ledarray/set"))
"""Routes where a fuzzed request may be a valid one (they ignore parameters they do not know,
print any text, or take ``value=50``): they read, or set the screen or LEDs. None moves the robot."""


def fuzz_requests(seed: int) -> Iterator[tuple[str, str, bytes]]:
    """Endless (kind, route, raw request bytes): what a hostile or broken HTTP client sends."""
    rng = random.Random(seed)
    end = b"Host: robot\r\nConnection: close\r\n\r\n"
    while True:
        kind = rng.choice(("long-url", "long-header", "many-headers", "bad-method", "garbage", "bad-encoding",
                           "bad-version", "bad-body", "bad-params", "not-found", "null-byte", "wrong-method"))
        route = rng.choice(ROUTES).encode()
        if kind == "long-url":
            data = b"GET " + route + b"?value=" + b"1" * rng.choice((9000, 20000, 100000)) + b" HTTP/1.1\r\n" + end
        elif kind == "long-header":
            data = b"GET " + route + b" HTTP/1.1\r\nX-Long: " + b"a" * rng.choice((9000, 70000)) + b"\r\n" + end
        elif kind == "many-headers":
            data = b"GET " + route + b" HTTP/1.1\r\n" + b"".join(b"X-%d: 1\r\n" % i for i in range(300)) + end
        elif kind == "bad-method":
            method = rng.choice((b"FOO", b"G\xffT", b"get", b"GET GET", b"\x16\x03\x01", b"(", b"PRI"))
            data = method + b" " + route + b" HTTP/1.1\r\n" + end
        elif kind == "garbage":
            data, route = rng.randbytes(rng.randrange(1, 3000)), b"-"
        elif kind == "bad-encoding":
            target = rng.choice((route + b"?value=\xff\xfe", route + b"?value=%C3%28", b"/\xc3\x28",
                                 route + b"?%ff=%fe"))
            header = rng.choice((b"X-Bad: \xff\xfe\r\n", b"Host\xff: x\r\n", b""))
            data = b"GET " + target + b" HTTP/1.1\r\n" + header + end
        elif kind == "bad-version":
            data = b"GET " + route + b" " + rng.choice((b"HTTP/9.9", b"HTTX/1.1", b"HTTP/1", b"")) + b"\r\n" + end
        elif kind == "bad-body":
            data = b"POST " + route + b" HTTP/1.1\r\n" + rng.choice(
                (b"Content-Length: -1\r\n", b"Content-Length: abc\r\n", b"Transfer-Encoding: chunked\r\n",
                 b"Content-Length: 5\r\nContent-Length: 7\r\n")) + end + rng.choice((b"zz\r\n", b"", b"12345"))
        elif kind == "bad-params":
            data = b"GET " + route + b"?" + rng.choice(BAD_PARAMS).encode() + b" HTTP/1.1\r\n" + end
        elif kind == "not-found":
            data = b"GET " + rng.choice((b"/../../etc/passwd", b"/%2e%2e/", b"/robot", b"//", b"/x" * 500)) + \
                b" HTTP/1.1\r\n" + end
            route = b"-"
        elif kind == "null-byte":
            data = b"GET " + route + b"\x00 HTTP/1.1\r\n" + end
        else:
            data = rng.choice((b"POST ", b"DELETE ", b"PUT ")) + route + b" HTTP/1.1\r\n" + end
        yield kind, route.decode(), data


async def one_request(host: str, port: int, data: bytes, timeout: float) -> str:
    """Send one raw request on a new connection; the response's status code, or what went wrong."""
    try:
        reader, writer = await asyncio.wait_for(asyncio.open_connection(host, port), timeout)
    except (OSError, TimeoutError):
        return "no connection"
    try:
        writer.write(data)
        await writer.drain()
        line = await asyncio.wait_for(reader.readline(), timeout)
        found = re.match(rb"HTTP/1\.[01] (\d{3})", line)
        return found.group(1).decode() if found else ("closed" if not line else "not http")
    except (OSError, TimeoutError):
        return "closed" if not isinstance(sys.exc_info()[1], TimeoutError) else "timeout"
    finally:
        writer.close()
        with contextlib.suppress(OSError, TimeoutError):
            await asyncio.wait_for(writer.wait_closed(), timeout)


Connection = tuple[asyncio.StreamReader, asyncio.StreamWriter]


async def open_idle(host: str, port: int, count: int) -> list[Connection]:
    """``count`` keep-alive connections, each after one answered request, left open and silent
    (what a crashed or malicious client leaves behind)."""
    connections = []
    for _ in range(count):
        reader, writer = await asyncio.open_connection(host, port)
        writer.write(b"GET /hat/dip/get HTTP/1.1\r\nHost: robot\r\n\r\n")  # keep-alive, the default
        head = await reader.readuntil(b"\r\n\r\n")
        length = re.search(rb"Content-Length: (\d+)", head, re.IGNORECASE)
        await reader.readexactly(int(length.group(1)) if length else 0)
        connections.append((reader, writer))
    return connections


async def closed_by_server(connections: list[Connection], timeout: float) -> int:
    """How many of these connections the server has closed within ``timeout`` s (then ours close too)."""
    deadline = time.monotonic() + timeout

    async def closed(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> bool:
        try:
            return await asyncio.wait_for(reader.read(), max(deadline - time.monotonic(), 0.0)) == b""
        except (TimeoutError, OSError):
            return False
        finally:
            writer.close()

    return sum(await asyncio.gather(*(closed(r, w) for r, w in connections)))


async def fuzz_http(host: str, port: int, count: int, seed: int, concurrency: int = 16,
                    timeout: float = 10.0) -> Counter[tuple[str, str, str]]:
    """Send ``count`` fuzzed requests, ``concurrency`` at a time; counts of (kind, route, status)."""
    results: Counter[tuple[str, str, str]] = Counter()
    requests = fuzz_requests(seed)
    left = count

    async def worker() -> None:
        nonlocal left
        while left > 0:
            left -= 1
            kind, route, data = next(requests)
            results[kind, route, await one_request(host, port, data, timeout)] += 1

    await asyncio.gather(*(worker() for _ in range(concurrency)))
    return results


# ---------------------------------------------------------------------- the stack


def query_burst(session: zenoh.Session, robot: str, count: int, at_once: int = MAX_QUERIES) -> Counter[str]:
    """``count`` good queries on the camera's ``camera/snapshot`` and ``camera/frame``, ``at_once``
    in flight (the most a queryable answers at once): a class asking for pictures. Answers by kind."""
    body = codec.encode(m.Stop())

    def ask(i: int) -> list[str]:
        topic = keys.SNAPSHOT if i % 2 else keys.FRAME
        return ["ok" if r.ok is not None else r.err.payload.to_string()[-40:]
                for r in session.get(keys.key(robot, topic), payload=body, timeout=10.0)]

    with ThreadPoolExecutor(at_once) as pool:
        return Counter(answer for answers in pool.map(ask, range(count)) for answer in answers)


def rss_mib(pid: int) -> float:
    """Resident set size of a process, MiB (0 if it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


@dataclass
class Stack:
    """`icefloe up` of the simulated robot with the hostile runs' services, in ``folder``."""

    folder: Path
    services: tuple[str, ...] = STACK
    extra_toml: str = ""
    config_path: Path = field(init=False)
    config: RobotConfig = field(init=False)
    web_port: int = field(init=False)
    proc: subprocess.Popen[bytes] | None = None

    def __post_init__(self) -> None:
        self.web_port = free_port()
        self.config_path = robot_config(self.folder, f"hostile{os.getpid()}",
                                        f"services = {json.dumps(list(self.services))}\n{self.extra_toml}\n"
                                        f"[webapi]\nport = {self.web_port}\nhost = \"127.0.0.1\"\n")
        self.config = config_mod.load(self.config_path)
        self.log_path = self.folder / "up.log"

    def start(self) -> None:
        self._log = open(self.log_path, "wb")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen([sys.executable, "-m", "icefloe.cli", "up", str(self.config_path), "--no-viz"],
                                     stdout=self._log, stderr=subprocess.STDOUT, cwd=ROOT, start_new_session=True,
                                     env={**os.environ, "PYTHONUNBUFFERED": "1"})

    def session(self, timeout: float = 60.0) -> zenoh.Session:
        """A plain Zenoh session to the robot's router, once it listens."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                return raw_session(self.config)
            except zenoh.ZError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.3)

    def output(self) -> str:
        return self.log_path.read_text(errors="replace")

    def pids(self) -> dict[str, list[int]]:
        return children(self.config_path)

    def rss(self) -> dict[str, float]:
        return {name: sum(rss_mib(p) for p in pids) for name, pids in sorted(self.pids().items())}

    def wait_alive(self, session: zenoh.Session, timeout: float = 90.0) -> None:
        """Until every service holds its liveliness token (and answers on its keys)."""
        want = {keys.alive_key(self.config.name, s) for s in (*self.services, "router")}
        deadline = time.monotonic() + timeout
        alive: set[str] = set()
        while time.monotonic() < deadline:
            replies = session.liveliness().get(keys.alive_key(self.config.name, "*"), timeout=2.0)
            alive = {str(r.ok.key_expr) for r in replies if r.ok is not None}
            if want <= alive:
                if "camera" in self.services:
                    self._wait_frames(session, deadline)
                return
            if self.proc is not None and self.proc.poll() is not None:
                break
            time.sleep(0.5)
        raise RuntimeError(f"not alive: {sorted(want - alive)}\n{self.output()[-3000:]}")

    def _wait_frames(self, session: zenoh.Session, deadline: float, count: int = 3) -> None:
        """Until the camera has detected ``count`` frames: the start of a run is the camera at work
        (its first frames take it from about 80 to 95 MiB; that is not what an attacker did)."""
        subscriber = session.declare_subscriber(keys.key(self.config.name, keys.LANDMARKS),
                                                zenoh.handlers.FifoChannel(16))
        try:
            seen = 0
            while seen < count:
                if subscriber.handler.try_recv() is not None:
                    seen += 1
                elif time.monotonic() > deadline:
                    raise RuntimeError(f"the camera detected {seen} frames, not {count}\n{self.output()[-3000:]}")
                else:
                    time.sleep(0.1)
        finally:
            subscriber.undeclare()

    def stop(self) -> int | None:
        if self.proc is None:
            return None
        self.proc.send_signal(signal.SIGINT)
        try:
            code = self.proc.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            code = self.proc.wait()
        self._log.close()
        return code


class LogCounter:
    """Counts the log lines each service puts on the bus ``log`` key (only well-formed ones: the
    hostile run puts garbage there too)."""

    def __init__(self, session: zenoh.Session, robot: str) -> None:
        self.lines: Counter[str] = Counter()
        self.texts: list[str] = []
        decoder = msgspec.msgpack.Decoder(m.Log)

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                entry = decoder.decode(sample.payload.to_bytes())
            except (msgspec.DecodeError, ValueError):
                return
            self.lines[entry.service] += 1
            if len(self.texts) < 100_000:
                self.texts.append(f"{entry.service}: {entry.text}")

        self._sub = session.declare_subscriber(keys.key(robot, keys.LOG), on_sample)

    def take(self) -> Counter[str]:
        """The counts so far, and start again from zero."""
        lines, self.lines = self.lines, Counter()
        return lines

    def close(self) -> None:
        self._sub.undeclare()


def output_lines(text: str) -> Counter[str]:
    """Lines per process in `icefloe up`'s output (each prefixed ``[name]``)."""
    counts: Counter[str] = Counter()
    for line in text.splitlines():
        found = re.match(r"\[(\S+)\s*\] ", line)
        if found:
            counts[found.group(1)] += 1
    return counts


def truth(session: zenoh.Session, robot: str) -> m.SimState:
    """The simulator's state (true pose, duty), from its ``sim/control`` queryable."""
    for reply in session.get(keys.key(robot, keys.SIM_CONTROL), payload=codec.encode(m.SimControl()),
                             encoding=codec.MSGPACK, timeout=10.0):
        if reply.ok is not None:
            return msgspec.msgpack.decode(reply.ok.payload.to_bytes(), type=m.SimState)
    raise RuntimeError("sim/control did not answer")


def moved(a: m.SimState, b: m.SimState) -> float:
    """How far the robot went between two states, m."""
    return math.hypot(b.x - a.x, b.y - a.y)


# ---------------------------------------------------------------------- main


def idle_connections(stack: Stack, count: int) -> None:
    """webapi's RSS with ``count`` idle keep-alive connections, and after it closed them."""
    from icefloe.services.webapi.server import KEEPALIVE_S

    async def run() -> tuple[float, float, int]:
        idle = await open_idle("127.0.0.1", stack.web_port, count)
        with_them = stack.rss()["webapi"]
        closed = await closed_by_server(idle, KEEPALIVE_S + 10.0)
        await asyncio.sleep(1.0)
        return with_them, stack.rss()["webapi"], closed

    before = stack.rss()["webapi"]
    with_them, after, closed = asyncio.run(run())
    print(f"\n{count} idle keep-alive connections: webapi {before:.1f} MiB before, {with_them:.1f} with them, "
          f"{after:.1f} after it closed {closed} of them (keep-alive {KEEPALIVE_S:g} s)")


BOUND_MIB = 10.0
"""The bound we hold every process to: RSS at the end of a run at most this much above its start
(docs/hostile-input.md; measured growth was at most 4.4 MiB)."""


def _table(rows: dict[str, list[float]], heads: list[str]) -> None:
    print(f"  {'process':<18}" + "".join(f"{h:>10}" for h in heads) + f"{'growth':>10}  bound {BOUND_MIB:g} MiB")
    for name, values in rows.items():
        growth = values[-1] - values[0]
        print(f"  {name:<18}" + "".join(f"{v:10.1f}" for v in values) + f"{growth:+10.1f}  "
              + ("ok" if growth <= BOUND_MIB else "OVER"))


def _rss_over(stack: Stack, steps: int, run_step: Callable[[int], object]) -> dict[str, list[float]]:
    """RSS of every process before the first of ``steps`` steps and after each one."""
    rss: dict[str, list[float]] = {name: [v] for name, v in stack.rss().items()}
    for i in range(steps):
        run_step(i)
        for name, v in stack.rss().items():
            rss.setdefault(name, [0.0]).append(v)
    return rss


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--payloads", type=int, default=100_000)
    p.add_argument("--requests", type=int, default=50_000)
    p.add_argument("--idle", type=int, default=500, help="idle keep-alive connections left open")
    p.add_argument("--burst", type=int, default=4_000, help=f"good camera queries, {MAX_QUERIES} at a time")
    p.add_argument("--rate", type=float, default=10_000.0, help="bad payloads per second, at most")
    p.add_argument("--steps", type=int, default=4, help="RSS read after each of this many parts of a run")
    p.add_argument("--services", default=",".join(STACK), help="the services of the robot (default: %(default)s)")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args()
    services = tuple(args.services.split(","))
    stack = Stack(Path(tempfile.mkdtemp(prefix="hostile-")), services=services)
    robot = stack.config.name
    heads = ["start", *(f"{100 * (i + 1) // args.steps}%" for i in range(args.steps))]
    print(f"robot {robot} ({', '.join(services)}), output in {stack.log_path}")
    stack.start()
    session = stack.session()
    try:
        stack.wait_alive(session)
        time.sleep(10.0)  # settled: the camera and localizer have seen frames, buffers are warm
        counter = LogCounter(session, robot)
        state = truth(session, robot) if "sim" in services else None

        def report(lines_before: Counter[str]) -> Counter[str]:
            time.sleep(3.0)  # the last queries time out, queues drain, counts of lines come
            nonlocal state
            on_bus, output = counter.take(), output_lines(stack.output())
            print(f"  log lines on the bus: {sum(on_bus.values())} ({dict(on_bus)})")
            print(f"  lines of output: {sum((output - lines_before).values())} ({dict(output - lines_before)})")
            print(f"  tracebacks in the output so far: {stack.output().count('Traceback')}")
            if state is not None:
                now = truth(session, robot)
                print(f"  robot moved {moved(state, now) * 1000:.2f} mm; duty {now.duty_left}, {now.duty_right}")
                state = now
            return output

        lines = output_lines(stack.output())
        if args.payloads:
            t0 = time.monotonic()
            sent: Counter[str] = Counter()
            rss = _rss_over(stack, args.steps, lambda i: sent.update(
                flood(session, robot, args.payloads // args.steps, args.seed + i, args.rate)))
            print(f"\n{args.payloads} bad payloads in {time.monotonic() - t0:.1f} s over {len(sent)} keys "
                  f"(puts and queries); RSS, MiB:")
            _table(rss, heads)
            lines = report(lines)
        if args.requests:
            t0 = time.monotonic()
            answers: Counter[tuple[str, str, str]] = Counter()
            rss = _rss_over(stack, args.steps, lambda i: answers.update(asyncio.run(
                fuzz_http("127.0.0.1", stack.web_port, args.requests // args.steps, args.seed + 10 + i))))
            print(f"\n{args.requests} fuzzed HTTP requests in {time.monotonic() - t0:.1f} s; RSS, MiB:")
            _table(rss, heads)
            codes = Counter(status for (_, _, status) in answers.elements())
            print(f"  answers: {dict(sorted(codes.items()))}, 200 only from "
                  f"{sorted({route for (_, route, status) in answers if status == '200'})}")
            lines = report(lines)
        if args.burst and "camera" in services:
            t0 = time.monotonic()
            got: Counter[str] = Counter()
            rss = _rss_over(stack, args.steps, lambda i: got.update(
                query_burst(session, robot, args.burst // args.steps)))
            print(f"\n{args.burst} good camera queries (snapshot, frame), {MAX_QUERIES} at a time, in "
                  f"{time.monotonic() - t0:.1f} s; RSS, MiB:")
            _table(rss, heads)
            print(f"  answers: {dict(got)}")
            lines = report(lines)
        if args.idle:
            idle_connections(stack, args.idle)
        counter.close()
    finally:
        session.close()
        code = stack.stop()
        print(f"\nicefloe up exited with {code}; output in {stack.log_path}")


if __name__ == "__main__":
    main()
