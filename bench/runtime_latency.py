"""Publish -> receive latency between two processes: the icefloe runtime vs raw zenoh-python.

    .venv/bin/python bench/runtime_latency.py [--count 2000] [--rate 500] [--block 100] [--rounds 3] [--stages]

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

With ``--stages`` it also measures two designs of that hop built here from the
same parts as the runtime, without the rest of `Node` (own-key check, codec),
and prints where the time goes (p50 and p99 of each stage, from timestamps taken
at each step of the same messages):

* thread: what the runtime does: Zenoh's channel read by a reader thread of
  ours, which queues the sample and wakes the loop with
  ``call_soon_threadsafe``; the loop decodes.
* direct: Zenoh's own thread calls us (``Callback(indirect=False)``) and wakes
  the loop with ``call_soon_threadsafe``: one thread hop fewer. Tried in the
  runtime for issue 29 and left: no clear gain in latency on the build machine,
  and under a flood on a loaded machine it let fewer samples through (Zenoh's
  one worker thread waits for the GIL per sample; docs/runtime.md).

Stages: *to Python*: the sender's stamp to the first Python line on the
receiving side; *to loop*: from there to the event loop's wake-up callback;
*to task*: from the wake-up to the ``async for`` body, decoding included. It
also prints what the pieces of the hop cost one thread, with no waiting
(`costs`).
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
from collections.abc import Callable
from pathlib import Path

from common import robot_config

ROOT = Path(__file__).resolve().parent.parent
VARIANTS = ("raw", "raw-fifo", "runtime")
STAGED = ("thread", "direct")
"""Designs of the hop built from the same parts, measured with ``--stages`` (see above)."""
DEADLINE_S = 30.0
"""A receiver gives up this long after the sender should have finished (lost messages)."""


def _robot(variant: str) -> str:
    """The robot name whose ``odom/pose`` a variant's receiver reads."""
    return "lat-" + variant


def _receive(config_path: str, variant: str, count: int, wait_s: float) -> dict:
    """Receiver role: latencies in ns of ``count`` messages, and the stages of each for the
    variants that can tell them."""
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
    elif variant in STAGED:
        run_async(asyncio.wait_for(_receive_staged(cfg, key, variant, count, latencies, stages), wait_s))
    else:
        run_async(asyncio.wait_for(_receive_runtime(cfg, variant, count, latencies, stages), wait_s))
    return {"latencies": latencies[:count], "stages": stages[:count]}


async def _receive_runtime(cfg, variant: str, count: int, latencies: list[int],  # type: ignore[no-untyped-def]
                           stages: list[tuple[int, int, int]]) -> None:
    from icefloe.runtime import Node
    from icefloe.schemas import keys

    woke = [0]

    class TimedWake(asyncio.Event):
        def set(self) -> None:  # the loop runs the wake-up the reader thread asked for
            woke[0] = time.monotonic_ns()
            super().set()

    async with Node("bench-rx", cfg) as node:
        sub = node.subscribe(keys.ODOM_POSE, latest=False, maxsize=count, robot=_robot(variant))
        sub._wake = TimedWake()
        arrived = [0]
        decode = sub._decode

        def timed_decode(raw):  # type: ignore[no-untyped-def]
            arrived[0] = int(raw.received * 1e9)  # taken by our first Python line, on the reader thread
            return decode(raw)

        sub._decode = timed_decode
        print("ready", flush=True)
        async for pose in sub:
            now = time.monotonic_ns()
            latencies.append(now - pose.stamp)
            stages.append((arrived[0] - pose.stamp, woke[0] - arrived[0], now - woke[0]))
            if len(latencies) >= count:
                break


async def _receive_staged(cfg, key: str, variant: str, count: int, latencies: list[int],  # type: ignore[no-untyped-def]
                          stages: list[tuple[int, int, int]]) -> None:
    """The hop as ``variant`` makes it (see the module's doc), timed at each step."""
    from collections import deque

    import msgspec
    import zenoh

    from icefloe.runtime import raw_session
    from icefloe.schemas import messages as m

    decoder = msgspec.msgpack.Decoder(m.Pose)
    loop = asyncio.get_running_loop()
    items: deque[tuple[bytes, int]] = deque()
    lock = threading.Lock()
    wake = asyncio.Event()
    pending = [False]
    woke = [0]

    def set_wake() -> None:
        woke[0] = time.monotonic_ns()
        wake.set()

    def on_sample(sample: zenoh.Sample) -> None:
        item = (sample.payload.to_bytes(), time.monotonic_ns())
        with lock:
            items.append(item)
            if pending[0]:
                return
            pending[0] = True
        loop.call_soon_threadsafe(set_wake)

    session = raw_session(cfg)
    if variant == "thread":
        sub = session.declare_subscriber(key, zenoh.handlers.DefaultHandler())

        def read() -> None:
            for sample in sub.handler:
                on_sample(sample)

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
    else:
        sub = session.declare_subscriber(key, zenoh.handlers.Callback(on_sample, indirect=False))
    print("ready", flush=True)
    try:
        while len(latencies) < count:
            with lock:
                item = items.popleft() if items else None
                if item is None:
                    pending[0] = False
                    wake.clear()
            if item is None:
                await wake.wait()
                continue
            pose = decoder.decode(item[0])
            now = time.monotonic_ns()
            latencies.append(now - pose.stamp)
            stages.append((item[1] - pose.stamp, woke[0] - item[1], now - woke[0]))
    finally:
        sub.undeclare()
        if variant == "thread":
            reader.join(2.0)
        session.close()


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

        def typed(pub: Publisher) -> Callable[[], None]:
            return lambda: pub.put(pose())

        def raw(pub: zenoh.Publisher) -> Callable[[], None]:
            return lambda: pub.put(codec.encode(pose()))

        for variant in variants:
            if variant == "runtime":  # a Node of the receiver's robot, publishing as a service does
                node = await Node("bench-tx", msgspec.structs.replace(cfg, name=_robot(variant))).__aenter__()
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
        if "runtime" in variants:
            node.close()

    run_async(run())


def _round(config_path: Path, variants: list[str], count: int, rate: float, block: int) -> dict[str, dict]:
    me = [sys.executable, __file__, "--config", str(config_path), "--count", str(count)]
    wait_s = count * len(variants) / rate + DEADLINE_S
    folder = Path(tempfile.mkdtemp())
    receivers = {}
    for variant in variants:
        rx = subprocess.Popen([*me, "--role", "rx", "--variants", variant, "--wait", str(wait_s),
                               "--out", str(folder / f"{variant}.json")], stdout=subprocess.PIPE, text=True)
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
    runtime does, queueing and taking a sample (lock, deque), ``call_soon_threadsafe`` (the
    runtime's wake-up) and a byte through a socket pair (send + recv: a wake-up tried and left)."""
    import socket
    from collections import deque

    import uvloop

    from icefloe.runtime import RawSample
    from icefloe.schemas import codec
    from icefloe.schemas import messages as m

    payload = codec.encode(m.Pose(stamp=1, x=1.0, y=2.0, theta=0.3, v=0.1, w=0.0))
    raw = RawSample("icefloe/sim/odom/pose", payload, codec.MSGPACK, 0.0)
    out: dict[str, float] = {}

    def timed(name: str, step) -> None:  # type: ignore[no-untyped-def]
        start = time.perf_counter()
        for _ in range(n):
            step()
        out[name] = (time.perf_counter() - start) / n * 1e6

    timed("decode", lambda: codec.decode(raw.payload, raw.encoding, m.Pose, raw.key))
    items: deque[RawSample] = deque(maxlen=64)
    lock = threading.Lock()

    def queue() -> None:
        with lock:
            items.append(RawSample("icefloe/sim/odom/pose", payload, codec.MSGPACK, time.monotonic()))
        with lock:
            items.popleft()

    timed("queue", queue)
    a, b = socket.socketpair()
    timed("socket wake", lambda: (a.send(b"\0"), b.recv(4096)))
    a.close(), b.close()
    loop = uvloop.new_event_loop()
    timed("call_soon_threadsafe", lambda: loop.call_soon_threadsafe(int))
    loop.close()
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--count", type=int, default=2000, help="messages per variant and round")
    p.add_argument("--rate", type=float, default=500.0, help="messages per second")
    p.add_argument("--block", type=int, default=100, help="messages a variant gets in one turn")
    p.add_argument("--rounds", type=int, default=3, help="rounds, each with fresh receiver processes")
    p.add_argument("--stages", action="store_true",
                   help="also measure two designs of the hop (thread, direct) and print the stages")
    p.add_argument("--role", choices=["rx", "tx"], help=argparse.SUPPRESS)
    p.add_argument("--variants", help=argparse.SUPPRESS)
    p.add_argument("--wait", type=float, help=argparse.SUPPRESS)
    p.add_argument("--out", help=argparse.SUPPRESS)
    p.add_argument("--config", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.role == "rx":
        Path(args.out).write_text(json.dumps(_receive(args.config, args.variants, args.count, args.wait)))
        return
    if args.role == "tx":
        _send(args.config, args.variants.split(","), args.count, args.rate, args.block)
        return

    variants = [*VARIANTS, *(STAGED if args.stages else ())]
    config_path = robot_config(Path(tempfile.mkdtemp()), "bench")
    router = subprocess.Popen([sys.executable, "-m", "icefloe.router", "--config", str(config_path)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(1.0)
    results: dict[str, list[int]] = {v: [] for v in variants}
    stages: dict[str, list[list[int]]] = {v: [] for v in variants}
    load = os.getloadavg()[0]
    try:
        for _ in range(args.rounds):
            for variant, got in _round(config_path, variants, args.count, args.rate, args.block).items():
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
        print(f"{'':10} {'to Python':>17} {'to loop':>17} {'to task':>17}")
        for variant in ("runtime", *STAGED):
            columns = list(zip(*stages[variant], strict=True))
            print(f"{variant:10} " + " ".join(f"{_pct(list(c), 0.5):7.1f} / {_pct(list(c), 0.99):7.1f}"
                                              for c in columns))
        print("what the pieces cost one thread, no waiting (µs): "
              + ", ".join(f"{name} {us:.2f}" for name, us in costs().items()))
    for variant in ("runtime", *(STAGED if args.stages else ())):
        rt = results[variant]
        for ref in ("raw", "raw-fifo"):
            raw = results[ref]
            print(f"ratio {variant}/{ref}: p50 {_pct(rt, 0.5) / _pct(raw, 0.5):.2f}x, "
                  f"p99 {_pct(rt, 0.99) / _pct(raw, 0.99):.2f}x  (goal: within 1.25x; "
                  f"mean {ref} {statistics.mean(raw) / 1e3:.1f} µs, {variant} {statistics.mean(rt) / 1e3:.1f} µs)")


if __name__ == "__main__":
    main()
