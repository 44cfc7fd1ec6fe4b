"""Benchmark: recording and replaying the whole simulated robot.

    .venv/bin/python bench/record_replay.py                  # 2 rounds of 3 windows of 30 s, and one more
    .venv/bin/python bench/record_replay.py --seconds 60 --rounds 3

What runs (all real processes): `icefloe up --no-viz` on the default simulated robot (router,
info, sim, hwbridge, odometry, localizer, camera, power, oled, webapi: every key at its default
rate), driven in a circle with ``cmd/twist`` at 10 Hz throughout, and a raw zenoh-python
subscriber that sees everything (the reference). Four windows of ``--seconds``, one after the other:

1. no recorder;
2. ``icefloe record`` of every key (camera images too), at its default niceness;
3. ``icefloe record --exclude camera/image``;
4. no recorder again.

What it prints:

* recording size per minute of each recorder, next to the bytes the same keys put on the bus
  (MessagePack, uncompressed) in the same window, and each recorder's CPU;
* hwbridge's cycle wake-up percentiles (its own histogram, from shared memory) in each window:
  the windows without a recorder are the reference; each window, then each condition's windows
  together;
* replay of the full recording at ``--rate 10`` under another robot name into a raw subscriber
  that counts every message: duration, throughput, messages lost (per key if any); next to it, the
  rate at which the same file is read and turned back into bus payloads with no bus at all.

Not a test: figures depend on the machine. Record them in docs/record-replay.md.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from common import cpu_seconds, free_port, read_state, robot_config

ROOT = Path(__file__).resolve().parent.parent
ICEFLOE = [sys.executable, "-m", "icefloe.cli"]


class Spy:
    """A raw zenoh-python subscriber to every key of a robot: counts and bytes per key."""

    def __init__(self, session, key_expr: str) -> None:
        self.counts: Counter[str] = Counter()
        self.bytes: Counter[str] = Counter()
        self.first = self.last = 0.0
        self._sub = session.declare_subscriber(key_expr, self._on_sample)

    def _on_sample(self, sample) -> None:
        key = str(sample.key_expr)
        self.counts[key] += 1
        self.bytes[key] += len(sample.payload)
        self.last = time.monotonic()
        self.first = self.first or self.last

    def take(self) -> tuple[Counter[str], Counter[str]]:
        counts, size = self.counts, self.bytes
        self.counts, self.bytes = Counter(), Counter()
        return counts, size


def figures(hist: list[int], cycles: int, overruns: int) -> dict:
    """Wake-up percentiles (µs) of a latency histogram (hwbridge's bins)."""
    from icefloe.services.hwbridge.control import percentiles

    p50, p99, p999, pmax = percentiles(hist, (0.5, 0.99, 0.999, 1.0))
    return {"p50": p50 * 1e6, "p99": p99 * 1e6, "p99.9": p999 * 1e6, "max": pmax * 1e6,
            "cycles": cycles, "overruns": overruns, "hist": hist}


def hist_window(shared, seconds: float) -> dict:
    """hwbridge's wake-up figures over ``seconds``, from its shared-memory histogram."""
    state0, hist0 = read_state(shared), list(shared.hist)
    time.sleep(seconds)
    state1, hist1 = read_state(shared), list(shared.hist)
    return figures([b - a for a, b in zip(hist0, hist1, strict=True)], state1["cycles"] - state0["cycles"],
                   state1["overruns"] - state0["overruns"])


def combined(windows: list[dict]) -> dict:
    """The figures of several windows taken together (their histograms added)."""
    hist = [sum(counts) for counts in zip(*(w["hist"] for w in windows), strict=True)]
    return figures(hist, sum(w["cycles"] for w in windows), sum(w["overruns"] for w in windows))


def record_window(config: Path, out: Path, shared, spy: Spy, seconds: float, *extra: str) -> dict:
    """One window with ``icefloe record`` running: its file size, CPU, and hwbridge's figures meanwhile."""
    recorder = subprocess.Popen([*ICEFLOE, "record", "-o", str(out), "--config", str(config), *extra],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    assert recorder.stderr is not None
    first = recorder.stderr.readline()  # "recording ... to FILE": subscribed
    assert first.startswith("recording"), first
    time.sleep(1.0)
    spy.take()
    cpu0, t0 = cpu_seconds(recorder.pid), time.monotonic()
    figures = hist_window(shared, seconds)
    cpu = (cpu_seconds(recorder.pid) - cpu0) / (time.monotonic() - t0)
    counts, size = spy.take()
    recorder.send_signal(signal.SIGINT)
    err = first + recorder.communicate(timeout=180)[1]  # niced on a busy machine, it may take a while
    assert recorder.returncode == 0, err
    return {**figures, "cpu": cpu, "file": out, "bus_counts": counts, "bus_bytes": size, "log": err.strip()}


async def replay_window(config: Path, recording: Path, robot: str, rate: float) -> dict:
    """Replay ``recording`` at ``rate`` under ``robot`` into a counting subscriber."""
    from icefloe import config as config_mod
    from icefloe.bag import Bag
    from icefloe.runtime import raw_session

    session = raw_session(config_mod.load(config))
    spy = Spy(session, f"icefloe/{robot}/**")
    await asyncio.sleep(0.5)
    start = time.monotonic()
    proc = await asyncio.create_subprocess_exec(*ICEFLOE, "replay", str(recording), "--rate", str(rate),
                                                "--robot", robot, "--config", str(config),
                                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    out = (await proc.communicate())[0].decode()
    wall = time.monotonic() - start
    await asyncio.sleep(1.0)
    session.close()
    assert proc.returncode == 0, out
    bag = Bag([recording], robot=robot)
    in_file: Counter[str] = Counter(e.channel.key for e in bag.entries())
    return {"wall": wall, "duration": duration_s(recording), "in_file": in_file, "received": spy.counts,
            "span": spy.last - spy.first, "log": out.strip().splitlines()[-1]}


def duration_s(recording: Path) -> float:
    """From the first to the last message of a recording, s."""
    from icefloe.bag import Bag

    times = [e.log_time for e in Bag([recording]).entries()]
    return (max(times) - min(times)) * 1e-9


def transcode_rate(recording: Path) -> float:
    """Reference: messages per second read from the file and turned into bus payloads, no bus."""
    from icefloe.bag import Bag
    from icefloe.bag.channels import payload

    start = time.process_time()
    n = sum(1 for e in Bag([recording]).entries() if payload(e.channel, e.data) is not None)
    return n / (time.process_time() - start)


def drive(config: Path, stop: asyncio.Event) -> asyncio.Task:
    async def run() -> None:
        from icefloe import config as config_mod
        from icefloe.runtime import Node
        from icefloe.schemas import keys
        from icefloe.schemas import messages as m

        async with Node("bench", config_mod.load(config)) as node:
            twist = node.publisher(keys.TWIST)
            while not stop.is_set():  # a 0.3 m circle: the camera keeps seeing markers
                twist.put(m.Twist(v=0.15, w=0.5))
                await asyncio.sleep(0.1)
            node.publisher(keys.STOP).put(m.Stop())

    return asyncio.create_task(run())


async def connect(config, timeout: float = 30.0):
    """A raw session to the robot's router, once it listens."""
    import zenoh

    from icefloe.runtime import raw_session

    deadline = time.monotonic() + timeout
    while True:
        try:
            return raw_session(config)
        except zenoh.ZError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.5)


async def up_and_running(session, robot: str, up: subprocess.Popen, timeout: float = 90.0) -> None:
    """Wait until every service of the robot holds its liveliness token, and a little more."""
    from icefloe.config import ALL_SERVICES

    deadline = time.monotonic() + timeout
    want = {f"icefloe/{robot}/alive/{s}" for s in ALL_SERVICES}
    while True:
        replies = await asyncio.to_thread(lambda: list(session.liveliness().get(f"icefloe/{robot}/alive/*")))
        if want <= {str(r.ok.key_expr) for r in replies if r.ok is not None}:
            break
        if time.monotonic() > deadline or up.poll() is not None:
            raise SystemExit(f"the robot did not come up: {sorted(want)}")
        await asyncio.sleep(1.0)
    await asyncio.sleep(3.0)  # settled: the camera renders, the localizer has its first fix


def megabytes_per_minute(size: float, seconds: float) -> float:
    return size / seconds * 60 / 1e6


async def main_async(args: argparse.Namespace) -> None:
    from icefloe import config as config_mod
    from icefloe.services.hwbridge.shm import Shared, block_name

    tmp = Path(tempfile.mkdtemp(prefix="record-bench-"))
    name = f"recbench{os.getpid()}"
    config = robot_config(tmp, name, f"[webapi]\nport = {free_port()}\n")
    up = subprocess.Popen([*ICEFLOE, "up", str(config), "--no-viz"], stdout=open(tmp / "up.log", "wb"),  # noqa: SIM115
                          stderr=subprocess.STDOUT, start_new_session=True)
    stop = asyncio.Event()
    driver = None
    try:
        cfg = config_mod.load(config)
        session = await connect(cfg)
        spy = Spy(session, f"icefloe/{name}/**")
        await up_and_running(session, name, up)
        shared = Shared.attach(block_name(name))
        driver = drive(config, stop)
        await asyncio.sleep(3.0)
        loop = asyncio.get_running_loop()
        windows: list[tuple[str, dict]] = []  # (condition, figures), in the order measured
        for r in range(args.rounds):  # the conditions in turn, so a change in the machine's load hits all
            windows.append(("no recorder", await loop.run_in_executor(None, hist_window, shared, args.seconds)))
            windows.append(("recording all", await loop.run_in_executor(
                None, record_window, config, tmp / f"all{r}.mcap", shared, spy, args.seconds)))
            windows.append(("recording, no images", await loop.run_in_executor(
                None, record_window, config, tmp / f"noimages{r}.mcap", shared, spy, args.seconds,
                "--exclude", "camera/image")))
        windows.append(("no recorder", await loop.run_in_executor(None, hist_window, shared, args.seconds)))
        shared.close()
        stop.set()
        await driver
        replayed = await replay_window(config, tmp / "all0.mcap", f"{name}r", args.rate)
        session.close()
    finally:
        stop.set()
        up.send_signal(signal.SIGINT)
        with contextlib.suppress(subprocess.TimeoutExpired):
            up.wait(30)
    reference = await asyncio.to_thread(transcode_rate, tmp / "all0.mcap")
    report(args, tmp, windows, replayed, reference)


def report(args: argparse.Namespace, tmp: Path, windows: list[tuple[str, dict]], replayed: dict,
           reference: float) -> None:
    from icefloe.bag import Bag

    load = os.getloadavg()[0]
    print(f"record/replay bench: the whole simulated robot (icefloe up), driven; {args.rounds} rounds of "
          f"{args.seconds:.0f} s windows; {os.cpu_count()} CPUs, load average {load:.2f}; files in {tmp}")
    print("\nrecording size (zstd chunks, JSON messages), next to what the same keys put on the bus "
          "(MessagePack) in the same window; each window:")
    for condition, w in windows:
        if "file" not in w:
            continue
        size, seconds = w["file"].stat().st_size, duration_s(w["file"])
        kept = Counter(e.channel.key for e in Bag([w["file"]]).entries())
        bus = sum(n for k, n in w["bus_bytes"].items() if k in kept)
        print(f"  {condition:22} {megabytes_per_minute(size, seconds):6.2f} MB/min   bus "
              f"{megabytes_per_minute(bus, args.seconds):6.2f} MB/min   {sum(kept.values()) / seconds:5.0f} msg/s "
              f"on {len(kept)} keys ({seconds:.0f} s file);  recorder CPU {w['cpu'] * 100:4.1f} % of a core")
        print(f"    {w['log'].splitlines()[-1]}")
    print("\nhwbridge cycle wake-up (µs), each window in turn, then each condition's windows together:")
    print(f"  {'':24}{'p50':>7}{'p99':>7}{'p99.9':>7}{'max':>7}   cycles  overruns")

    def row(label: str, w: dict) -> None:
        print(f"  {label:24}{w['p50']:7.0f}{w['p99']:7.0f}{w['p99.9']:7.0f}{w['max']:7.0f}   "
              f"{w['cycles']:6d}  {w['overruns']:8d}")

    for condition, w in windows:
        row(condition, w)
    print("  " + "-" * 60)
    for condition in dict.fromkeys(c for c, _ in windows):
        row(condition, combined([w for c, w in windows if c == condition]))
    r = replayed
    lost = {k: n - r["received"][k] for k, n in r["in_file"].items() if r["received"][k] != n}
    sent = sum(r["in_file"].values())
    print(f"\nreplay of the first full recording at --rate {args.rate:g}: {r['duration']:.1f} s of recording, {sent} "
          f"messages, received over {r['span']:.2f} s ({sent / r['span']:.0f} msg/s; "
          f"{r['wall']:.1f} s with the process's start); lost: {sum(lost.values())}"
          + (f" {dict(lost)}" if lost else ""))
    print(f"  replay's own line: {r['log']}")
    print(f"  reference, the file read and turned into bus payloads, no bus: {reference:.0f} msg/s")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=30.0, help="length of each window (default 30)")
    p.add_argument("--rounds", type=int, default=2, help="times the three conditions are taken in turn (default 2)")
    p.add_argument("--rate", type=float, default=10.0, help="replay speed (default 10)")
    asyncio.run(main_async(p.parse_args()))


if __name__ == "__main__":
    main()
