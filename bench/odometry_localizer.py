"""Odometry and localizer figures: CPU at 1 kHz input, EKF time per landmark, square-run errors.

    .venv/bin/python bench/odometry_localizer.py [--seconds 10] [--seeds 5]

1. **Odometry CPU at 1 kHz ``hw/wheels``** (goal < 5 % of one core). Starts a
   Zenoh router and ``python -m icefloe.services.odometry`` as real processes;
   this script publishes ``hw/wheels`` every millisecond (a robot driving at
   0.2 m/s) and reads the odometry process's user + system CPU time from
   ``/proc/<pid>/stat`` over the window, then again at 100 Hz (hwbridge's default
   ``hw/wheels`` rate). Checks at the end that ``odom/pose``
   accounts for every count sent (no motion lost).
   References, same run and same input: a process that only subscribes to
   ``hw/wheels`` through the runtime and decodes each sample (the floor any
   runtime subscriber pays), one that lets Zenoh queue the samples in a
   FifoChannel and drains them 100 times a second (no Python callback per
   sample), one whose Zenoh session receives the samples but Python never
   reads them (the session's own cost), and the odometry process idle.
2. **Localizer update time per landmark observation** (goal < 1 ms):
   `Ekf.observe` in-process, median and 99th percentile. Reference: one
   `Ekf.predict` and one bare 2 x 2 `numpy.linalg.inv` (numpy's per-call floor).
3. **Square-run errors**: `icefloe/estimation/simrun.py`, the simulator's
   World driven four times round a 1 m square, no slip and with slip, encoder
   noise and 2 % outliers, over several seeds.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from common import cpu_percent, cpu_seconds

ROOT = Path(__file__).resolve().parent.parent
COUNTS_PER_MS = 0.2 * 1e-3 / (math.pi * 0.065 / 384)  # 0.2 m/s in counts per ms

FLOOR = """
import asyncio, sys
from icefloe.config import load
from icefloe.runtime import Node
from icefloe.schemas import keys

async def main():
    async with Node("floor", load(sys.argv[1])) as node:
        async for _ in node.subscribe(keys.WHEELS, latest=False, maxsize=4096):
            pass

asyncio.run(main())
"""

FLOOR_ZENOH = """
import asyncio, sys, zenoh
from icefloe.config import load
from icefloe.runtime import Node
from icefloe.schemas import keys

async def main():
    async with Node("floor-zenoh", load(sys.argv[1])) as node:
        # Zenoh receives every sample into a 1-slot ring; Python never looks: the cost of the session alone.
        sub = node.session.declare_subscriber(node.key(keys.WHEELS), zenoh.handlers.RingChannel(1))
        await asyncio.Event().wait()

asyncio.run(main())
"""

FLOOR_POLLED = """
import asyncio, sys, zenoh
from icefloe.config import load
from icefloe.runtime import Node
from icefloe.schemas import codec, keys, messages as m

async def main():
    async with Node("floor-polled", load(sys.argv[1])) as node:
        sub = node.session.declare_subscriber(node.key(keys.WHEELS), zenoh.handlers.FifoChannel(4096))
        while True:  # no Python callback per sample: Zenoh queues them, we drain 100 times a second
            await asyncio.sleep(0.01)
            while (s := sub.try_recv()) is not None:
                codec.decode(s.payload.to_bytes(), str(s.encoding), m.Wheels)

asyncio.run(main())
"""


def publish(config_path: Path, rate_hz: float, stop: threading.Event, sent: list[float],
            ready: threading.Event) -> None:
    """Publish hw/wheels at ``rate_hz`` (absolute deadlines), straight ahead at 0.2 m/s.

    ``sent`` = [distance so far in counts (fractional), samples]: updated in place, so a second
    call continues the same drive.
    """
    from icefloe.config import load
    from icefloe.runtime import MSGPACK, raw_session
    from icefloe.schemas import codec, keys
    from icefloe.schemas import messages as m

    cfg = load(config_path)
    period = 1.0 / rate_hz
    with raw_session(cfg) as session:
        pub = session.declare_publisher(keys.key(cfg.name, keys.WHEELS), encoding=MSGPACK)

        def put(ticks: int) -> None:
            pub.put(codec.encode(m.Wheels(stamp=time.time_ns(), ticks_left=ticks, ticks_right=ticks,
                                          speed_left=0.2, speed_right=0.2)))

        ready.set()
        deadline = time.monotonic()
        while not stop.is_set():
            sent[0] += COUNTS_PER_MS * 1000.0 * period
            sent[1] += 1
            put(math.floor(sent[0]))
            deadline += period
            delay = deadline - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        for _ in range(3):  # the robot stands still: repeat the last counts so a dropped last sample shows none
            time.sleep(0.05)
            put(math.floor(sent[0]))
        time.sleep(0.3)  # let the last samples through before the session closes


def last_pose(config_path: Path) -> tuple[float, float]:
    """x of the latest odom/pose, m, and its count equivalent."""
    from icefloe.config import load
    from icefloe.runtime import Node
    from icefloe.schemas import keys

    async def get() -> float:
        async with Node("bench", load(config_path)) as node:
            sub = node.subscribe(keys.ODOM_POSE)
            pose = await asyncio.wait_for(anext(sub), 5.0)
            return pose.x

    x = asyncio.run(get())
    return x, x / (math.pi * 0.065 / 384)


def odometry_cpu(seconds: float, tmp: Path) -> list[tuple[str, str]]:
    port = 27600 + os.getpid() % 1000
    config = tmp / "robot.toml"
    config.write_text(
        f'extends = "{ROOT / "deploy" / "robots" / "sim.toml"}"\nname = "bench"\nrun_dir = "{tmp}"\n\n'
        # the drawing's wheels, as COUNTS_PER_MS assumes (the bench measures CPU, not the wheels)
        '[geometry]\nwheel_diameter = 0.065\ntrack = 0.156\n'
        f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\nconnect = ["tcp/127.0.0.1:{port}"]\n')
    log = open(tmp / "log.txt", "wb")  # noqa: SIM115 - closed below
    py = [sys.executable]
    router = subprocess.Popen([*py, "-m", "icefloe.router", "--config", str(config)], stdout=log, stderr=log)
    time.sleep(1.0)
    procs = {
        "odometry process": subprocess.Popen([*py, "-m", "icefloe.services.odometry", "--config", str(config)],
                                             stdout=log, stderr=log),
        "reference: runtime subscribe + decode only": subprocess.Popen([*py, "-c", FLOOR, str(config)],
                                                                       stdout=log, stderr=log),
        "reference: Zenoh FifoChannel drained at 100 Hz + decode": subprocess.Popen(
            [*py, "-c", FLOOR_POLLED, str(config)], stdout=log, stderr=log),
        "reference: Zenoh session receiving, Python never reads": subprocess.Popen(
            [*py, "-c", FLOOR_ZENOH, str(config)], stdout=log, stderr=log),
        # The same with Zenoh's own thread pools instead of the services' one thread (docs/runtime.md).
        "reference: the same, Zenoh's default thread pools": subprocess.Popen(
            [*py, "-c", FLOOR_ZENOH, str(config)], stdout=log, stderr=log, env={**os.environ, "ZENOH_RUNTIME": "()"}),
    }
    rows = []
    try:
        time.sleep(2.0)
        rows.append(("odometry process, idle (no input)",
                     f"{cpu_percent(procs['odometry process'].pid, seconds / 2):6.2f} % of one core"))
        sent = [0.0, 0]
        for rate in (1000.0, 100.0):
            stop, ready = threading.Event(), threading.Event()
            thread = threading.Thread(target=publish, args=(config, rate, stop, sent, ready))
            thread.start()
            ready.wait(30)
            time.sleep(1.0)
            c0 = {name: cpu_seconds(p.pid) for name, p in procs.items()}
            n0, t0 = sent[1], time.monotonic()
            time.sleep(seconds)
            wall = time.monotonic() - t0
            achieved = (sent[1] - n0) / wall
            stop.set()
            thread.join()
            for name, p in procs.items():
                pct = 100.0 * (cpu_seconds(p.pid) - c0[name]) / wall
                goal = "   (goal < 5 %)" if name == "odometry process" else ""
                rows.append((f"{name}, hw/wheels at {achieved:.0f} Hz", f"{pct:6.2f} % of one core{goal}"))
        x, counts = last_pose(config)
        rows.append(("  counts sent vs integrated (odom/pose x)",
                     f"{math.floor(sent[0])} vs {counts:.2f} (x = {x:.4f} m, {sent[1]} samples)"))
    finally:
        odo = procs.pop("odometry process")
        for proc in procs.values():  # throwaway references: no need to be polite
            proc.kill()
            proc.wait()
        odo.send_signal(2)
        try:
            code = odo.wait(10)
            rows.append(("odometry exit code after SIGINT", str(code)))
        except subprocess.TimeoutExpired:
            odo.kill()
            rows.append(("odometry exit after SIGINT", "DID NOT EXIT within 10 s (killed)"))
        router.send_signal(2)
        router.wait(10)
        log.close()
    return rows


def localizer_timing(n: int = 20000) -> list[tuple[str, str]]:
    import numpy as np

    from icefloe.estimation.ekf import Ekf
    from icefloe.worldmap import load_world

    lab = {mk.id: (mk.x, mk.y) for mk in load_world("lab").markers}
    ekf = Ekf(lab, sigma=(0.02, 0.02, 0.02))
    r, b = ekf.expected(1)

    def timed(fn, *args) -> list[float]:
        out = []
        for _ in range(n):
            t0 = time.perf_counter_ns()
            fn(*args)
            out.append((time.perf_counter_ns() - t0) / 1000.0)
        return out

    def fmt(samples: list[float]) -> str:
        q = statistics.quantiles(samples, n=100)
        return f"median {statistics.median(samples):7.1f} us, p99 {q[98]:7.1f} us"

    observe = timed(ekf.observe, 1, r, b)
    predict = timed(ekf.predict, 0.0, 0.0, 0.0)
    a = np.eye(2)
    inv = timed(np.linalg.inv, a)
    return [("Ekf.observe, one landmark", fmt(observe) + "   (goal < 1000 us)"),
            ("reference: Ekf.predict", fmt(predict)),
            ("reference: numpy.linalg.inv of a 2x2", fmt(inv))]


def square_runs(seeds: int) -> list[tuple[str, str]]:
    import logging

    from icefloe import config as config_mod
    from icefloe.estimation.simrun import Scenario, square_run

    logging.getLogger("icefloe.simrun").setLevel(logging.ERROR)
    cfg = config_mod.load()
    rows = []
    for label, kw in (("no slip", {}),
                      ("slip 0.1, encoder noise 0.02, 2 % outliers",
                       {"slip": 0.1, "encoder_noise": 0.02, "outlier_rate": 0.02, "unknown_rate": 0.05})):
        results = [square_run(cfg, Scenario(seed=s, **kw)) for s in range(1, seeds + 1)]

        def worst(f, results=results) -> float:
            return max(f(r) for r in results)

        rows.append((f"{label}: odometry final (worst of {seeds} seeds)",
                     f"{worst(lambda r: r.odometry.final_pos) * 100:5.2f} cm "
                     f"{math.degrees(worst(lambda r: r.odometry.final_heading)):5.2f} deg"))
        rows.append((f"{label}: odometry max over the run",
                     f"{worst(lambda r: r.odometry.max_pos) * 100:5.2f} cm "
                     f"{math.degrees(worst(lambda r: r.odometry.max_heading)):5.2f} deg"))
        rows.append((f"{label}: localizer max over the run",
                     f"{worst(lambda r: r.localizer.max_pos) * 100:5.2f} cm "
                     f"{math.degrees(worst(lambda r: r.localizer.max_heading)):5.2f} deg"))
        rows.append((f"{label}: gate rejected / injected outliers",
                     f"{sum(r.rejected for r in results)} / {sum(r.injected_outliers for r in results)}"
                     f" of {sum(r.sightings for r in results)} sightings"))
    rows.append(("(goals: odometry no slip < 1 cm, < 1 deg; localizer with slip < 5 cm, < 3 deg)", ""))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="CPU measuring window")
    parser.add_argument("--seeds", type=int, default=5, help="square runs per scenario")
    args = parser.parse_args()
    print(f"$ {' '.join([Path(sys.executable).name, *sys.argv])}")
    print(f"{os.cpu_count()} CPUs\n")
    with tempfile.TemporaryDirectory() as tmp:
        rows = odometry_cpu(args.seconds, Path(tmp))
    rows += localizer_timing()
    rows += square_runs(args.seeds)
    for name, value in rows:
        print(f"{name:60s} {value}")


if __name__ == "__main__":
    main()
