"""Benchmark: the web API's HTTP bridge to the bus (``/bus/``) next to a raw Zenoh client, in one run.

    .venv/bin/python bench/http_bridge.py                    # about 20 s
    .venv/bin/python bench/http_bridge.py --commands 400 --samples 600

What runs (all real processes, the robot's topology): the robot's Zenoh router, the simulator,
hwbridge (publishing ``hw/wheels`` at 500 Hz here, so its period hides little) and the web API.
This process is the client, both ways:

* **command**: ``cmd/wheels`` sent with ``PUT /bus/cmd/wheels`` (aiohttp, a kept-alive connection),
  or put on a raw zenoh-python session (MessagePack), alternately, one at a time. Measured from
  just before the send to the first ``hw/wheels`` whose ``target_left`` (what hwbridge commands
  the wheel) has moved towards the new speed: hwbridge has seen it (the next command waits for
  the ramp to end). Both include hwbridge's cycle
  and its ``hw/wheels`` period (2 ms), alike.
* **stream**: ``oled/text`` put on a raw session every 20 ms, its send time in the text; one
  Server-Sent Events client of ``GET /bus/oled/text`` and one raw Zenoh subscriber receive the
  same samples. Measured from the put to the arrival (SSE: the event parsed by the client).

Prints p50/p99/max of each, in ms. Not a test: the figures depend on the machine (docs/webapi.md).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import aiohttp
from common import free_port, robot_config

from icefloe import config as config_mod
from icefloe.runtime import MSGPACK, raw_session
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m

SPEEDS = (0.1, 0.15)
"""cmd/wheels alternates between these left (and right) speeds, m/s: each command changes the target."""


def start(service: str, cfg: Path, folder: Path) -> subprocess.Popen[bytes]:
    module = "icefloe.router" if service == "router" else f"icefloe.services.{service}"
    with open(folder / f"{service}.log", "wb") as log:
        return subprocess.Popen([sys.executable, "-m", module, "--config", str(cfg)], stdout=log,
                                stderr=subprocess.STDOUT, start_new_session=True)


def stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for proc in reversed(procs):
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)


def figures(name: str, ns: list[int]) -> str:
    ms = sorted(v / 1e6 for v in ns)
    p99 = ms[min(len(ms) - 1, int(len(ms) * 0.99))]
    return f"  {name:<22} n={len(ms):4d}  p50 {statistics.median(ms):6.2f} ms  p99 {p99:6.2f} ms  max {ms[-1]:6.2f} ms"


class Targets:
    """hw/wheels as it arrives (on a Zenoh thread): the newest target_left and when it changed."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        self.target: float | None = None
        self.changed = asyncio.Event()
        self.at = 0

    def on_sample(self, sample) -> None:  # type: ignore[no-untyped-def]
        now = time.monotonic_ns()
        wheels = codec.decode(sample.payload.to_bytes(), str(sample.encoding), m.Wheels, "hw/wheels")
        if wheels.target_left != self.target:
            self.target = wheels.target_left
            self.at = now
            self.loop.call_soon_threadsafe(self.changed.set)


async def commands(config, base: str, count: int) -> dict[str, list[int]]:  # type: ignore[no-untyped-def]
    session = raw_session(config)
    targets = Targets(asyncio.get_running_loop())
    sub = session.declare_subscriber(keys.key(config.name, keys.WHEELS), targets.on_sample)
    pub = session.declare_publisher(keys.key(config.name, keys.WHEELS_CMD), encoding=MSGPACK)
    out: dict[str, list[int]] = {"http PUT": [], "raw zenoh put": []}
    try:
        async with aiohttp.ClientSession() as http:
            for i in range(2 * count + 20):  # the first 20 warm up both paths
                speed = SPEEDS[i % 2]
                variant = "http PUT" if (i // 2) % 2 else "raw zenoh put"
                targets.changed.clear()
                sent = time.monotonic_ns()
                if variant == "http PUT":
                    async with http.put(f"{base}/bus/cmd/wheels", json={"left": speed, "right": speed}) as r:
                        assert r.status == 200, await r.text()
                else:
                    pub.put(codec.encode(m.WheelSpeeds(left=speed, right=speed)))
                while targets.at < sent:  # the first change after the send (it may ramp on from there)
                    targets.changed.clear()
                    await asyncio.wait_for(targets.changed.wait(), 5.0)
                if i >= 20:
                    out[variant].append(targets.at - sent)
                while targets.target is None or abs(targets.target - speed) > 1e-9:  # settled: the next starts clean
                    targets.changed.clear()
                    await asyncio.wait_for(targets.changed.wait(), 5.0)
                await asyncio.sleep(0.005)
            pub.put(codec.encode(m.WheelSpeeds(left=0.0, right=0.0)))
    finally:
        pub.undeclare()
        sub.undeclare()
        session.close()
    return out


async def stream(config, base: str, count: int) -> dict[str, list[int]]:  # type: ignore[no-untyped-def]
    session = raw_session(config)
    key = keys.key(config.name, keys.OLED_TEXT)
    out: dict[str, list[int]] = {"SSE client": [], "raw zenoh subscriber": []}

    def on_sample(sample) -> None:  # type: ignore[no-untyped-def]
        now = time.monotonic_ns()
        text = codec.decode(sample.payload.to_bytes(), str(sample.encoding), m.OledText, key).text
        out["raw zenoh subscriber"].append(now - int(text))

    sub = session.declare_subscriber(key, on_sample)
    pub = session.declare_publisher(key, encoding=MSGPACK)
    try:
        async with aiohttp.ClientSession() as http, \
                http.get(f"{base}/bus/oled/text", headers={"Accept": "text/event-stream"}) as r:
            assert r.status == 200, await r.text()
            await asyncio.sleep(1.0)  # the bridge's subscriber reaches the router

            async def publish() -> None:
                for _ in range(count):
                    pub.put(codec.encode(m.OledText(text=str(time.monotonic_ns()))))
                    await asyncio.sleep(0.02)

            sender = asyncio.create_task(publish())
            async for line in r.content:
                if line.startswith(b"data:"):
                    now = time.monotonic_ns()
                    out["SSE client"].append(now - int(json.loads(line[5:])["value"]["text"]))
                    if len(out["SSE client"]) >= count:
                        break
            await sender
    finally:
        pub.undeclare()
        sub.undeclare()
        session.close()
    return out


async def wait_ready(config, base: str) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + 90
    async with aiohttp.ClientSession() as http:
        while True:
            try:
                async with http.get(f"{base}/bus/hw/wheels") as r:
                    if r.status == 200:
                        return
            except aiohttp.ClientConnectionError:
                pass
            if time.monotonic() > deadline:
                raise SystemExit("http_bridge: the robot did not come up within 90 s")
            await asyncio.sleep(0.2)


async def bench(config, args: argparse.Namespace) -> None:  # type: ignore[no-untyped-def]
    base = f"http://127.0.0.1:{config.webapi.port}"
    await wait_ready(config, base)
    print(f"command -> hwbridge sees it (hw/wheels target), {args.commands} commands, alternating:")
    for name, ns in (await commands(config, base, args.commands)).items():
        print(figures(name, ns))
    print(f"bus -> client, {args.samples} samples of oled/text at 50 Hz, the same samples to both:")
    for name, ns in (await stream(config, base, args.samples)).items():
        print(figures(name, ns))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--commands", type=int, default=200, help="commands of each kind (default 200)")
    parser.add_argument("--samples", type=int, default=300, help="stream samples (default 300)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="icefloe-bench-http-") as tmp:
        folder = Path(tmp)
        cfg = robot_config(folder, "bench_http", (
            f'[hwbridge]\nwheels_rate_hz = 500.0\n[webapi]\nhost = "127.0.0.1"\nport = {free_port()}\n'))
        config = config_mod.load(cfg)
        procs = [start("router", cfg, folder)]
        try:
            time.sleep(1.0)
            procs += [start(s, cfg, folder) for s in ("sim", "hwbridge", "webapi")]
            asyncio.run(bench(config, args))
        finally:
            stop(procs)


if __name__ == "__main__":
    main()
