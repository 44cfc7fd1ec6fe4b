"""Publish -> receive latency between two processes: the icefloe runtime vs raw zenoh-python.

    .venv/bin/python bench/runtime_latency.py [--count 1500] [--rate 500] [--block 10] [--rounds 2] [--stages]

Every variant uses the same topology as a robot (a router process, a sender
process and a receiver process, all Zenoh clients with a service's thread
pools), the same payload (a MessagePack `Pose`, stamped by the sender just
before its put) and the same clock (CLOCK_MONOTONIC, shared by the processes
of one machine).

The receivers of all variants run at once, each on a key of its own, and the
sender feeds them in turn, ``--block`` messages at a time at ``--rate``, the
order of the variants rotating from turn to turn: a load that comes and goes on
a shared machine hits every variant alike, and only one receiver works at a
time. Each round starts fresh receiver processes.

* raw: the receiver's zenoh-python callback (``declare_subscriber(key,
  callback)``, run on a Python thread zenoh-python starts) decodes the payload
  with msgspec and takes the time: the lowest a Python receiver can do.
* raw-fifo: the same, received the idiomatic zenoh-python way, ``for sample in
  subscriber`` over Zenoh's own FIFO channel in the main thread.
* runtime: the receiver takes the time when its ``async for`` over
  ``Node.subscribe(...)`` yields the decoded message, i.e. including the hop
  from Zenoh's thread into asyncio. Its messages are sent by a `Node` publisher.
* before: the same, through the runtime's subscription as it was before issue
  29 (`Before`, below: the reader thread wakes the loop with
  ``call_soon_threadsafe``; a `RawSample` under a lock; `codec.decode`).

With ``--stages`` the two runtime receivers also take the time at each step of
the same messages and print where it goes (p50 and p99 of each stage; the
timing costs the receivers a little): *to queue*: the sender's stamp to the
sample in the subscription's queue (the sender, the router, Zenoh's receiving
side and our reader thread's copy); *to loop*: from there to the event loop's
wake-up callback; *to task*: from the wake-up to the ``async for`` body,
decoding included. It also prints what the pieces of the hop cost one thread,
with no waiting (`costs`).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from common import robot_config

ROOT = Path(__file__).resolve().parent.parent
VARIANTS = ("raw", "raw-fifo", "runtime", "before")
RUNTIMES = ("runtime", "before")
"""The variants that are the runtime (one as it is, one as it was): the ratios are theirs."""
DEADLINE_S = 30.0
"""A receiver gives up this long after the sender should have finished (lost messages)."""


def _robot(variant: str) -> str:
    """The robot name whose ``odom/pose`` a variant's receiver reads."""
    return "lat-" + variant


class Before:
    """The runtime's `Subscription` before issue 29, as it was (typed, fifo), to measure before
    and after in one run: our reader thread builds a `RawSample`, queues it under a lock and
    wakes the loop with ``call_soon_threadsafe`` (the loop wakes while the thread still holds
    the GIL), then `asyncio.Event`; the loop decodes with `codec.decode`."""

    def __init__(self, node: Any, key_expr: str, type_: type, maxsize: int) -> None:
        import zenoh

        from icefloe.runtime import deliver_on_thread

        self.key_expr, self._type, self._node = key_expr, type_, node
        self.rejected = self.skipped = 0
        self._loop = asyncio.get_running_loop()
        self._items: deque[Any] = deque(maxlen=maxsize)
        self._lock = threading.Lock()
        self._wake = asyncio.Event()
        self._wake_pending = False
        self._closed = False
        self._sub = node.session.declare_subscriber(key_expr, zenoh.handlers.DefaultHandler())
        self._reader = deliver_on_thread(self._sub.handler, self._on_sample, f"icefloe {key_expr}", node.limited)

    def _on_sample(self, sample: Any) -> None:
        from icefloe.runtime import RawSample

        raw = RawSample(str(sample.key_expr), sample.payload.to_bytes(), str(sample.encoding), time.monotonic())
        with self._lock:
            if len(self._items) == self._items.maxlen:
                self.skipped += 1
            self._items.append(raw)
            if self._wake_pending:
                return
            self._wake_pending = True
        with contextlib.suppress(RuntimeError):
            self._loop.call_soon_threadsafe(self._wake.set)

    def __aiter__(self) -> Before:
        return self

    async def __anext__(self) -> Any:
        from icefloe.errors import BadPayload
        from icefloe.schemas import codec

        while True:
            with self._lock:
                raw = self._items.popleft() if self._items else None
                if raw is None:
                    self._wake_pending = False
                    self._wake.clear()
            if raw is None:
                if self._closed:
                    raise StopAsyncIteration
                await self._wake.wait()
                continue
            if not self._node.own_key(self.key_expr, raw.key):
                self.rejected += 1
                continue
            try:
                return codec.decode(raw.payload, raw.encoding, self._type, raw.key)
            except BadPayload as exc:
                self.rejected += 1
                self._node.limited.warning(self.key_expr, "dropped: %s", exc)

    def close(self) -> None:
        from icefloe.runtime import join_reader

        self._closed = True
        self._sub.undeclare()
        join_reader(self._reader, self._node.log)
        self._wake.set()


def _receive(config_path: str, variant: str, count: int, wait_s: float, timed: bool) -> dict:
    """Receiver role: latencies in ns of ``count`` messages, and (``timed``, runtime variants)
    the stages of each."""
    import msgspec
    import zenoh

    from icefloe import config as config_mod
    from icefloe.runtime import raw_session, run_async
    from icefloe.schemas import keys
    from icefloe.schemas import messages as m

    cfg = config_mod.load(config_path)
    key = keys.key(_robot(variant), keys.ODOM_POSE)
    latencies: list[int] = []
    stages: list[tuple[int, int, int]] = []
    decoder = msgspec.msgpack.Decoder(m.Pose)
    if variant == "raw-fifo":
        session = raw_session(cfg)
        sub = session.declare_subscriber(key)  # Zenoh's FIFO channel
        give_up = threading.Timer(wait_s, sub.undeclare)  # messages lost: end the iteration
        give_up.start()
        print("ready", flush=True)
        for sample in sub:
            pose = decoder.decode(sample.payload.to_bytes())
            latencies.append(time.monotonic_ns() - pose.stamp)
            if len(latencies) >= count:
                break
        give_up.cancel()
        with contextlib.suppress(zenoh.ZError):  # undeclared already, if we gave up
            sub.undeclare()
        session.close()
    elif variant == "raw":
        session = raw_session(cfg)
        done = threading.Event()

        def on_sample(sample: zenoh.Sample) -> None:
            pose = decoder.decode(sample.payload.to_bytes())
            latencies.append(time.monotonic_ns() - pose.stamp)
            if len(latencies) >= count:
                done.set()

        sub = session.declare_subscriber(key, on_sample)
        print("ready", flush=True)
        done.wait(wait_s)
        sub.undeclare()
        session.close()
    else:
        with contextlib.suppress(TimeoutError):  # messages lost: write what came
            run_async(asyncio.wait_for(_receive_runtime(cfg, variant, count, latencies, stages, timed), wait_s))
    return {"latencies": latencies[:count], "stages": stages[:count]}


class _TimedQueue(deque):  # type: ignore[type-arg]
    """A subscription's queue that notes when the sample it hands out was queued (--stages)."""

    def __init__(self, maxlen: int, queued: Callable[[Any], float]) -> None:
        super().__init__(maxlen=maxlen)
        self._queued, self.last = queued, 0

    def popleft(self) -> Any:
        item = super().popleft()
        self.last = int(self._queued(item) * 1e9)
        return item


async def _receive_runtime(cfg: Any, variant: str, count: int, latencies: list[int],
                           stages: list[tuple[int, int, int]], timed: bool) -> None:
    from icefloe.runtime import Node
    from icefloe.schemas import keys

    woke = [0]

    def timed_wake(wake: Callable[[], object]) -> Callable[[], None]:
        def wake_up() -> None:  # the loop runs the wake-up the reader thread asked for
            woke[0] = time.monotonic_ns()
            wake()
        return wake_up

    async with Node("bench-rx", cfg) as node:
        sub: Any
        if variant == "runtime":
            sub = node.subscribe(keys.ODOM_POSE, latest=False, maxsize=count, robot=_robot(variant))
            if timed:
                sub._items = queue = _TimedQueue(count, lambda item: item[3])
                sub._wakeup._callback = timed_wake(sub._wakeup._callback)
        else:
            sub = Before(node, keys.key(_robot(variant), keys.ODOM_POSE), keys.ODOM_POSE.type, count)
            if timed:
                sub._items = queue = _TimedQueue(count, lambda raw: raw.received)
                sub._wake.set = timed_wake(sub._wake.set)
        print("ready", flush=True)
        try:
            async for pose in sub:
                now = time.monotonic_ns()
                latencies.append(now - pose.stamp)
                if timed:
                    stages.append((queue.last - pose.stamp, woke[0] - queue.last, now - woke[0]))
                if len(latencies) >= count:
                    break
        finally:
            sub.close()


def _send(config_path: str, variants: list[str], count: int, rate: float, block: int) -> None:
    """Sender role: ``count`` messages to each variant's key, ``block`` at a time, in turn."""
    import msgspec
    import zenoh

    from icefloe import config as config_mod
    from icefloe.runtime import MSGPACK, Node, Publisher, raw_session, run_async
    from icefloe.schemas import codec, keys
    from icefloe.schemas import messages as m

    cfg = config_mod.load(config_path)
    period = 1.0 / rate

    def pose() -> m.Pose:
        return m.Pose(stamp=time.monotonic_ns(), x=1.0, y=2.0, theta=0.3, v=0.1, w=0.0)

    async def run() -> None:
        session = raw_session(cfg)
        puts: dict[str, Callable[[], None]] = {}
        nodes = []

        def typed(pub: Publisher) -> Callable[[], None]:
            return lambda: pub.put(pose())

        def raw(pub: zenoh.Publisher) -> Callable[[], None]:
            return lambda: pub.put(codec.encode(pose()))

        for variant in variants:
            if variant in RUNTIMES:  # a Node of the receiver's robot, publishing as a service does
                node = await Node("bench-tx", msgspec.structs.replace(cfg, name=_robot(variant))).__aenter__()
                nodes.append(node)
                puts[variant] = typed(node.publisher(keys.ODOM_POSE))
            else:
                puts[variant] = raw(session.declare_publisher(keys.key(_robot(variant), keys.ODOM_POSE),
                                                              encoding=MSGPACK))
        await asyncio.sleep(1.0)  # the declarations reach the router and the receivers
        deadline = time.monotonic()
        for turn in range(-(-count // block)):
            order = variants[turn % len(variants):] + variants[:turn % len(variants)]
            for variant in order:
                for _ in range(min(block, count - turn * block)):
                    puts[variant]()
                    deadline += period
                    await asyncio.sleep(max(0.0, deadline - time.monotonic()))
        await asyncio.sleep(0.5)
        session.close()
        for node in nodes:
            node.close()

    run_async(run())


def _round(config_path: Path, variants: list[str], count: int, rate: float, block: int,
           timed: bool) -> dict[str, dict]:
    me = [sys.executable, __file__, "--config", str(config_path), "--count", str(count)]
    wait_s = count * len(variants) / rate + DEADLINE_S
    folder = Path(tempfile.mkdtemp())
    receivers = {}
    for variant in variants:
        rx = subprocess.Popen([*me, "--role", "rx", "--variants", variant, "--wait", str(wait_s),
                               "--out", str(folder / f"{variant}.json"), *(["--stages"] if timed else [])],
                              stdout=subprocess.PIPE, text=True)
        receivers[variant] = rx
    for rx in receivers.values():
        assert rx.stdout is not None and rx.stdout.readline().strip() == "ready"
    subprocess.run([*me, "--role", "tx", "--variants", ",".join(variants), "--rate", str(rate),
                    "--block", str(block)], check=True)
    results = {}
    for variant, rx in receivers.items():
        rest = rx.communicate(timeout=wait_s + 30)[0].strip()
        if rest:  # Zenoh's own log lines go to stdout: show them, they are not our results
            print(f"[{variant} receiver] {rest}", file=sys.stderr)
        results[variant] = json.loads((folder / f"{variant}.json").read_text())
    return results


def _pct(values: list[int], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))] / 1e3


def costs(n: int = 20000) -> dict[str, float]:
    """What the pieces of the hop cost one thread, µs each, no waiting: decoding a Pose as the
    runtime does now and as it did (`codec.decode`), queueing and taking a sample now (a tuple,
    a deque) and before (a `RawSample`, a lock), and the wake-ups: an eventfd written and read
    (now) and ``call_soon_threadsafe`` (before)."""
    from icefloe.runtime import RawSample, _decoder
    from icefloe.schemas import codec, keys
    from icefloe.schemas import messages as m

    payload = codec.encode(m.Pose(stamp=1, x=1.0, y=2.0, theta=0.3, v=0.1, w=0.0))
    key = "icefloe/sim/odom/pose"
    out: dict[str, float] = {}

    def timed(name: str, step: Callable[[], object]) -> None:
        start = time.perf_counter()
        for _ in range(n):
            step()
        out[name] = (time.perf_counter() - start) / n * 1e6

    decode = _decoder(keys.ODOM_POSE)
    timed("decode", lambda: decode(payload, codec.MSGPACK, key))
    timed("decode before", lambda: codec.decode(payload, codec.MSGPACK, m.Pose, key))
    items: deque[Any] = deque(maxlen=64)

    def queue() -> None:
        items.append((key, payload, codec.MSGPACK, time.monotonic()))
        items.popleft()

    timed("queue", queue)
    lock = threading.Lock()

    def queue_before() -> None:
        with lock:
            items.append(RawSample(key, payload, codec.MSGPACK, time.monotonic()))
        with lock:
            items.popleft()

    timed("queue before", queue_before)
    fd = os.eventfd(0, os.EFD_NONBLOCK)
    timed("eventfd wake", lambda: (os.write(fd, b"\1\0\0\0\0\0\0\0"), os.read(fd, 64)))
    os.close(fd)
    loop = asyncio.new_event_loop()
    timed("call_soon_threadsafe", lambda: loop.call_soon_threadsafe(int))
    loop.close()
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--count", type=int, default=1500, help="messages per variant and round")
    p.add_argument("--rate", type=float, default=500.0, help="messages per second")
    p.add_argument("--block", type=int, default=10,
                   help="messages a variant gets in one turn (a few: a disturbance of a shared machine "
                        "falls on every variant alike, not on one variant's long block)")
    p.add_argument("--rounds", type=int, default=2, help="rounds, each with fresh receiver processes")
    p.add_argument("--stages", action="store_true",
                   help="the runtime receivers also time each step of the hop, and print where the time goes")
    p.add_argument("--role", choices=["rx", "tx"], help=argparse.SUPPRESS)
    p.add_argument("--variants", help=argparse.SUPPRESS)
    p.add_argument("--wait", type=float, help=argparse.SUPPRESS)
    p.add_argument("--out", help=argparse.SUPPRESS)
    p.add_argument("--config", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.role == "rx":
        result = _receive(args.config, args.variants, args.count, args.wait, args.stages)
        Path(args.out).write_text(json.dumps(result))
        return
    if args.role == "tx":
        _send(args.config, args.variants.split(","), args.count, args.rate, args.block)
        return

    variants = list(VARIANTS)
    config_path = robot_config(Path(tempfile.mkdtemp()), "bench")
    router = subprocess.Popen([sys.executable, "-m", "icefloe.router", "--config", str(config_path)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(1.0)
    results: dict[str, list[int]] = {v: [] for v in variants}
    stages: dict[str, list[list[int]]] = {v: [] for v in variants}
    load = os.getloadavg()[0]
    try:
        for _ in range(args.rounds):
            for variant, got in _round(config_path, variants, args.count, args.rate, args.block,
                                       args.stages).items():
                results[variant] += got["latencies"]
                stages[variant] += got["stages"]
    finally:
        router.terminate()
        router.wait()

    print(f"publish -> receive, two processes through a router, {args.rounds} x {args.count} messages per "
          f"variant at {args.rate:.0f} Hz, {args.block} at a time (µs); load average {load:.2f} at the start, "
          f"{os.getloadavg()[0]:.2f} at the end")
    print(f"{'':10} {'n':>6} {'p50':>8} {'p90':>8} {'p99':>8} {'max':>8}")
    for variant, lat in results.items():
        print(f"{variant:10} {len(lat):6d} {_pct(lat, 0.5):8.1f} {_pct(lat, 0.9):8.1f} "
              f"{_pct(lat, 0.99):8.1f} {max(lat) / 1e3:8.1f}")
    if args.stages:
        print("where the time goes, p50 / p99 of each stage (µs):")
        print(f"{'':10} {'to queue':>17} {'to loop':>17} {'to task':>17}")
        for variant in RUNTIMES:
            columns = list(zip(*stages[variant], strict=True))
            print(f"{variant:10} " + " ".join(f"{_pct(list(c), 0.5):7.1f} / {_pct(list(c), 0.99):7.1f}"
                                              for c in columns))
        print("what the pieces cost one thread, no waiting (µs): "
              + ", ".join(f"{name} {us:.2f}" for name, us in costs().items()))
    worst = 0.0
    for variant in RUNTIMES:
        rt = results[variant]
        for ref in ("raw", "raw-fifo"):
            raw = results[ref]
            p50, p99 = _pct(rt, 0.5) / _pct(raw, 0.5), _pct(rt, 0.99) / _pct(raw, 0.99)
            if variant == "runtime":
                worst = max(worst, p50, p99)
            print(f"ratio {variant}/{ref}: p50 {p50:.2f}x, p99 {p99:.2f}x  (goal: within 1.25x; "
                  f"mean {ref} {statistics.mean(raw) / 1e3:.1f} µs, {variant} {statistics.mean(rt) / 1e3:.1f} µs)")
    print(f"runtime: worst ratio {worst:.2f}x: " + ("within the goal" if worst <= 1.25 else "NOT within 1.25x"))


if __name__ == "__main__":
    main()
