"""Publish -> receive latency between two processes: the icefloe runtime vs raw zenoh-python.

    .venv/bin/python bench/runtime_latency.py [--count 2000] [--rate 500] [--rounds 3]

Both variants use the same topology as a robot (a router process, two client
processes), the same payload (a MessagePack `Pose`) and the same clock
(CLOCK_MONOTONIC, shared by processes on one machine). The rounds alternate so
that machine noise hits both alike.

* raw: `Publisher.put` of encoded bytes; the receiver's Zenoh callback decodes
  the payload with msgspec and takes the time (the lowest a Python receiver can do).
* raw-fifo: the same, received the idiomatic zenoh-python way, `for sample in
  subscriber` over Zenoh's own FIFO channel in the main thread.
* runtime: `Publisher.put(message)`; the receiver takes the time when its
  `async for` over `Node.subscribe(...)` yields the decoded message, i.e.
  including the hop from Zenoh's thread into asyncio.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import robot_config

ROOT = Path(__file__).resolve().parent.parent
VARIANTS = ("raw", "raw-fifo", "runtime")


def _receive(config_path: str, variant: str, count: int) -> list[int]:
    """Receiver role: latencies in ns of `count` messages."""
    from icefloe import config as config_mod
    from icefloe.runtime import Node, raw_session, run_async
    from icefloe.schemas import codec, keys
    from icefloe.schemas import messages as m

    cfg = config_mod.load(config_path)
    latencies: list[int] = []
    if variant == "raw-fifo":
        import msgspec
        import zenoh

        session = raw_session(cfg)
        decoder = msgspec.msgpack.Decoder(m.Pose)
        sub = session.declare_subscriber(keys.key(cfg.name, keys.ODOM_POSE))  # Zenoh's FIFO channel
        print("ready", flush=True)
        for sample in sub:
            pose = decoder.decode(sample.payload.to_bytes())
            latencies.append(time.monotonic_ns() - pose.stamp)
            if len(latencies) >= count:
                break
        sub.undeclare()
        session.close()
        return latencies
    if variant == "raw":
        import msgspec
        import zenoh

        session = raw_session(cfg)
        decoder = msgspec.msgpack.Decoder(m.Pose)

        def on_sample(sample: zenoh.Sample) -> None:
            pose = decoder.decode(sample.payload.to_bytes())
            latencies.append(time.monotonic_ns() - pose.stamp)

        sub = session.declare_subscriber(keys.key(cfg.name, keys.ODOM_POSE), on_sample)
        print("ready", flush=True)
        deadline = time.monotonic() + 60
        while len(latencies) < count and time.monotonic() < deadline:
            time.sleep(0.01)
        sub.undeclare()
        session.close()
        return latencies[:count]

    async def run() -> None:
        async with Node("bench-rx", cfg) as node:
            sub = node.subscribe(keys.ODOM_POSE, latest=False, maxsize=count)
            print("ready", flush=True)
            async for pose in sub:
                latencies.append(time.monotonic_ns() - pose.stamp)
                if len(latencies) >= count:
                    break

    run_async(asyncio.wait_for(run(), 60))
    _ = codec  # same codec as the raw variant
    return latencies


def _send(config_path: str, variant: str, count: int, rate: float) -> None:
    from icefloe import config as config_mod
    from icefloe.runtime import MSGPACK, Node, raw_session, run_async
    from icefloe.schemas import codec, keys
    from icefloe.schemas import messages as m

    cfg = config_mod.load(config_path)
    period = 1.0 / rate

    def pose() -> m.Pose:
        return m.Pose(stamp=time.monotonic_ns(), x=1.0, y=2.0, theta=0.3, v=0.1, w=0.0)

    if variant.startswith("raw"):

        session = raw_session(cfg)
        pub = session.declare_publisher(keys.key(cfg.name, keys.ODOM_POSE), encoding=MSGPACK)
        time.sleep(0.5)
        for _ in range(count):
            pub.put(codec.encode(pose()))
            time.sleep(period)
        time.sleep(0.5)
        session.close()
        return

    async def run() -> None:
        async with Node("bench-tx", cfg) as node:
            pub = node.publisher(keys.ODOM_POSE)
            await asyncio.sleep(0.5)
            for _ in range(count):
                pub.put(pose())
                await asyncio.sleep(period)
            await asyncio.sleep(0.5)

    run_async(run())


def _round(config_path: Path, variant: str, count: int, rate: float) -> list[int]:
    me = [sys.executable, __file__, "--config", str(config_path), "--variant", variant, "--count", str(count)]
    rx = subprocess.Popen([*me, "--role", "rx"], stdout=subprocess.PIPE, text=True)
    assert rx.stdout is not None
    assert rx.stdout.readline().strip() == "ready"
    time.sleep(0.3)
    subprocess.run([*me, "--role", "tx", "--rate", str(rate)], check=True)
    out, _ = rx.communicate(timeout=90)
    return json.loads(out)


def _pct(values: list[int], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))] / 1e3


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--count", type=int, default=2000)
    p.add_argument("--rate", type=float, default=500.0)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--role", choices=["rx", "tx"])
    p.add_argument("--variant", choices=VARIANTS)
    p.add_argument("--config")
    args = p.parse_args()
    if args.role == "rx":
        print(json.dumps(_receive(args.config, args.variant, args.count)))
        return
    if args.role == "tx":
        _send(args.config, args.variant, args.count, args.rate)
        return

    config_path = robot_config(Path(tempfile.mkdtemp()), "bench")
    router = subprocess.Popen([sys.executable, "-m", "icefloe.router", "--config", str(config_path)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(1.0)
    results: dict[str, list[int]] = {v: [] for v in VARIANTS}
    try:
        for _ in range(args.rounds):
            for variant in VARIANTS:
                results[variant] += _round(config_path, variant, args.count, args.rate)
    finally:
        router.terminate()
        router.wait()

    print(f"publish -> receive, two processes through a router, {args.rounds} x {args.count} messages "
          f"at {args.rate:.0f} Hz each (µs)")
    print(f"{'':10} {'n':>6} {'p50':>8} {'p90':>8} {'p99':>8} {'max':>8}")
    for variant, lat in results.items():
        print(f"{variant:10} {len(lat):6d} {_pct(lat, 0.5):8.1f} {_pct(lat, 0.9):8.1f} "
              f"{_pct(lat, 0.99):8.1f} {max(lat) / 1e3:8.1f}")
    rt = results["runtime"]
    for ref in ("raw", "raw-fifo"):
        raw = results[ref]
        print(f"ratio runtime/{ref}: p50 {_pct(rt, 0.5) / _pct(raw, 0.5):.2f}x, "
              f"p99 {_pct(rt, 0.99) / _pct(raw, 0.99):.2f}x  (goal: within 1.25x; "
              f"mean {ref} {statistics.mean(raw) / 1e3:.1f} µs, runtime {statistics.mean(rt) / 1e3:.1f} µs)")


if __name__ == "__main__":
    main()
