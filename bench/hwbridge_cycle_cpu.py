"""CPU of hwbridge's real-time cycle per period, standing and driving, next to the wake-ups alone.

    .venv/bin/python bench/hwbridge_cycle_cpu.py [--seconds 10] [--board penguinpi|icoboard] [--rest-rate-hz 0]

Starts `icefloe up` with the simulator and hwbridge only (on a free port), so the
cycle (``python -m icefloe.services.hwbridge.rt``, a process of its own) talks to the
simulator's board model over the real link: the PenguinPi's pseudo-terminal, or the
icoBoard's datagram socket. Over a window standing and one driving (`cmd/twist` at
10 Hz), it reads the cycle's CPU time from /proc and its period count from its
shared memory (`hw/loop`'s ``cycles``), and prints CPU per period and per second. Standing,
the cycle rests (``hwbridge.rest_rate_hz``, 50 Hz, docs/hwbridge.md): fewer, dearer periods
(each one a board exchange); ``--rest-rate-hz 0`` keeps it at the full rate, as before.

The reference, in the same windows: a process that does nothing but the cycle's
wake-ups (`rt.AbsoluteTimer` to an absolute deadline at ``hwbridge.rate_hz``, and
reading the clock), which is what a period costs here before any work. The
difference is the cycle's own work: commands in, one board step, state out.
Both are measured at once, so a load that comes and goes falls on both.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import cpu_seconds, read_state, robot_config, robot_processes

FLOOR = """
import sys, time
from icefloe.services.hwbridge.rt import AbsoluteTimer
period = round(1e9 / float(sys.argv[1]))
timer, count = AbsoluteTimer(), 0
deadline = time.monotonic_ns() + period
print("ready", flush=True)
while True:
    timer.sleep_until(deadline)
    woke = time.monotonic_ns()
    if woke < deadline:
        continue
    deadline += period
    if woke > deadline:
        deadline = woke + period
"""
"""The reference: the cycle's wake-ups and nothing else (`rt.Cycle.run` without `step`)."""


def cycle_pid(config: Path, runtime_dir: Path, timeout: float = 120.0) -> int:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        procs = robot_processes(config, runtime_dir)
        if procs.get("hwbridge (cycle)"):
            return procs["hwbridge (cycle)"][0]
        time.sleep(0.5)
    raise SystemExit(f"hwbridge's cycle not running after {timeout:.0f} s")


def measure(cycle: int, floor: int, shared, seconds: float) -> tuple[float, float, int, float]:  # type: ignore[no-untyped-def]
    """CPU µs per period of the cycle and of the floor over ``seconds``, the periods counted, and
    the cycle's CPU in % of a core."""
    c0, f0, n0, t0 = cpu_seconds(cycle), cpu_seconds(floor), read_state(shared)["cycles"], time.monotonic()
    time.sleep(seconds)
    c1, f1, n1, t1 = cpu_seconds(cycle), cpu_seconds(floor), read_state(shared)["cycles"], time.monotonic()
    periods = n1 - n0
    floor_periods = (t1 - t0) * RATE  # the floor keeps time as well as the cycle does
    return 1e6 * (c1 - c0) / periods, 1e6 * (f1 - f0) / floor_periods, periods, 100 * (c1 - c0) / (t1 - t0)


RATE = 1000.0


def main() -> None:
    global RATE
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=10.0, help="length of each window, s")
    p.add_argument("--board", choices=["penguinpi", "icoboard"], default="penguinpi", help="the simulated board")
    p.add_argument("--settle", type=float, default=5.0, help="wait this long once the cycle runs, s")
    p.add_argument("--rest-rate-hz", type=float, default=None,
                   help="hwbridge.rest_rate_hz for the robot (default: the config's; 0: the cycle never rests)")
    args = p.parse_args()
    from icefloe import config as config_mod
    from icefloe.services.hwbridge.shm import Shared, block_name

    folder = Path(tempfile.mkdtemp())
    board = ('[board]\nkind = "icoboard"\nprotocol = 2\n' if args.board == "icoboard" else "")
    rest = "" if args.rest_rate_hz is None else f"[hwbridge]\nrest_rate_hz = {args.rest_rate_hz}\n"
    config = robot_config(folder, f"cyclecpu{os.getpid()}", 'services = ["sim", "hwbridge"]\n' + board + rest)
    cfg = config_mod.load(str(config))
    RATE = cfg.hwbridge.rate_hz
    icefloe = [sys.executable, "-m", "icefloe.cli"]
    up = subprocess.Popen([*icefloe, "up", str(config), "--no-viz"], stdout=subprocess.DEVNULL,
                          stderr=subprocess.DEVNULL, start_new_session=True)
    floor = subprocess.Popen([sys.executable, "-c", FLOOR, str(RATE)], stdout=subprocess.PIPE, text=True)
    driver = None
    load = os.getloadavg()[0]
    try:
        assert floor.stdout is not None and floor.stdout.readline().strip() == "ready"
        cycle = cycle_pid(config, cfg.runtime_dir)
        shared = None
        deadline = time.monotonic() + 30.0
        while shared is None:
            try:
                shared = Shared.attach(block_name(cfg.name))
            except FileNotFoundError:
                if time.monotonic() > deadline:
                    raise SystemExit("hwbridge's shared memory did not appear") from None
                time.sleep(0.2)
        while not read_state(shared)["link_up"]:
            time.sleep(0.2)
        time.sleep(args.settle)
        standing = measure(cycle, floor.pid, shared, args.seconds)
        driver = subprocess.Popen([*icefloe, "pub", "cmd/twist", '{"v": 0.15, "w": 0.5}', "--rate", "10",
                                   "--config", str(config)], stdout=subprocess.DEVNULL)
        deadline = time.monotonic() + 60.0  # a busy machine takes seconds to start a Python
        while read_state(shared)["stop_reason"] != 0:
            if time.monotonic() > deadline:
                raise SystemExit("the robot did not drive within 60 s of `icefloe pub cmd/twist`")
            time.sleep(0.2)
        time.sleep(1.0)
        driving = measure(cycle, floor.pid, shared, args.seconds)
        if read_state(shared)["stop_reason"] != 0:
            raise SystemExit("the robot was not driving in the driving window")
        shared.close()
    finally:
        if driver is not None:
            driver.terminate()
        floor.kill()
        up.send_signal(signal.SIGINT)
        with contextlib.suppress(subprocess.TimeoutExpired):
            up.wait(60)
    rests = f"resting at {cfg.hwbridge.rest_rate_hz:g} Hz" if cfg.hwbridge.rests else "never resting"
    print(f"hwbridge cycle at {RATE:g} Hz ({rests}), {args.board} board (simulated), {args.seconds:g} s a window; "
          f"load average {load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end")
    print(f"  {'':10} {'periods':>8} {'cycle':>12} {'wake-ups alone':>15} {'the work':>12}   (CPU µs per period)")
    for label, (used, alone, periods, percent) in (("standing", standing), ("driving", driving)):
        print(f"  {label:10} {periods:8d} {used:10.1f} µs {alone:13.1f} µs {used - alone:10.1f} µs   "
              f"= {percent:.1f} % of a core ({periods / args.seconds:.0f} periods a second)")


if __name__ == "__main__":
    main()
