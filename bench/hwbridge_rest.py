"""Benchmark: a command's and a stop's latency from rest, with the cycle resting and without.

    .venv/bin/python bench/hwbridge_rest.py              # 20 of each per board and setting
    .venv/bin/python bench/hwbridge_rest.py --trials 5

What runs: the robot's router, the simulator and hwbridge as processes, for the PenguinPi
(firmware model on a pseudo-terminal) and the icoBoard v2 (model on its socket), each twice:
``hwbridge.rest_rate_hz = 0`` (the cycle never rests: as before resting) and the default
(50 Hz), both with ``rest_after_s = 0.3``. Each trial waits until the robot stands (and, when
it may, the cycle rests: the shared memory's rest word), then

* publishes ``cmd/wheels`` (0.2 m/s) and reads hwbridge's shared memory until the cycle has
  taken it (a non-zero target: command -> cycle), and until it has told the board a non-zero
  duty (command -> board told: on the icoBoard in the same period; the PenguinPi's demand
  stays 0 until the ramp, 2 m/s², is worth a count per 20 ms, and goes out with its next
  200 Hz exchange);
* drives 0.3 s, stops, waits until the robot stands again (and rests), then publishes
  ``cmd/stop`` and reads the shared memory until the cycle reports it confirmed by the board
  (``stop_confirmed``): stop -> confirmed, with the duty checked to stay 0 meanwhile.

Not a test: figures depend on the machine. Record them in docs/hwbridge.md.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import read_state, robot_config

from icefloe import config as config_mod
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.hwbridge.shm import Shared, block_name

ROOT = Path(__file__).resolve().parent.parent
BOARDS = {"penguinpi": "", "icoboard-v2": '[board]\nkind = "icoboard"\nbackend = "sim"\nprotocol = 2\n'}
SETTINGS = {"never rests (rest_rate_hz = 0)": 0.0, "rests (rest_rate_hz = 50)": 50.0}
SPIN_S = 0.00005
"""How often the shared memory is read while waiting, s."""


def until(what, timeout: float = 10.0) -> float:  # type: ignore[no-untyped-def]
    """Spin until ``what()`` is true; returns the monotonic time it was seen, s."""
    deadline = time.monotonic() + timeout
    while not what():
        if time.monotonic() > deadline:
            raise TimeoutError("timed out")
        time.sleep(SPIN_S)
    return time.monotonic()


async def stand(node: Node, shared: Shared, resting: bool) -> None:
    """Until the simulator's wheels have been still 0.3 s and, if it may, the cycle rests."""
    while True:
        s = await node.query(keys.SIM_CONTROL, m.SimControl(), timeout=5.0)
        if s.zero_duty_since >= 0 and s.sim_time - s.counts_changed >= 0.3 and (shared.rest() or not resting):
            return
        await asyncio.sleep(0.05)


async def trials(config_path: Path, count: int, resting: bool) -> dict:
    """Per kind of latency, ms; the largest duty while a stop from rest was confirmed; and the
    cycle's link and loop counters at the end (a resting link must not time out)."""
    config = config_mod.load(config_path)
    procs = [subprocess.Popen([sys.executable, "-m", module, "--config", str(config_path)],
                              cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True)
             for module in ("icefloe.router", "icefloe.services.sim", "icefloe.services.hwbridge")]
    taken, told, stops, worst, link = [], [], [], 0.0, {}
    try:
        async with Node("hwbridge_rest", config) as node:
            wheels, stop = node.publisher(keys.WHEELS_CMD), node.publisher(keys.STOP)
            await anext(node.subscribe(keys.WHEELS))  # hwbridge is up
            shared = Shared.attach(block_name(config.name))
            try:
                for _ in range(count):
                    await stand(node, shared, resting)
                    sent = time.monotonic()
                    wheels.put(m.WheelSpeeds(left=0.2, right=0.2))
                    taken.append(until(lambda: read_state(shared)["target_left"] != 0.0) - sent)
                    told.append(until(lambda: read_state(shared)["duty_left"] != 0.0) - sent)
                    for _ in range(6):
                        await asyncio.sleep(0.05)
                        wheels.put(m.WheelSpeeds(left=0.2, right=0.2))
                    stop.put(m.Stop())
                    await stand(node, shared, resting)
                    number = read_state(shared)["stop_confirmed"]
                    sent = time.monotonic()
                    stop.put(m.Stop())

                    def confirmed(number: int = number) -> bool:
                        nonlocal worst
                        state = read_state(shared)
                        worst = max(worst, abs(state["duty_left"]), abs(state["duty_right"]))
                        return state["stop_confirmed"] > number

                    stops.append(until(confirmed) - sent)
                link = {k: read_state(shared)[k] for k in ("timeouts", "late", "unmatched", "watchdog", "overruns")}
            finally:
                shared.close()
    finally:
        for p in reversed(procs):
            p.terminate()
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(10)
    return {"command -> cycle": [t * 1e3 for t in taken], "command -> board told": [t * 1e3 for t in told],
            "stop -> confirmed": [t * 1e3 for t in stops], "worst": [worst], "link": link}


def summary(name: str, values: list[float]) -> str:
    values = sorted(values)
    return (f"    {name:<26} p50 {statistics.median(values):6.2f}   p90 {values[int(0.9 * (len(values) - 1))]:6.2f}"
            f"   max {values[-1]:6.2f} ms")


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=20, help="commands and stops from rest, per board and setting")
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} at the start")
    with tempfile.TemporaryDirectory() as tmp:
        for board, toml in BOARDS.items():
            for label, rate in SETTINGS.items():
                folder = Path(tmp) / f"{board}{rate:g}"
                folder.mkdir()
                extra = f"{toml}[hwbridge]\nrest_rate_hz = {rate}\nrest_after_s = 0.3\n"
                name = f"rest{board.replace('-', '')}{rate:g}"
                got = await trials(robot_config(folder, name, extra), args.trials, rate > 0)
                print(f"{board}, {label}: {args.trials} commands and stops from rest")
                for kind, values in got.items():
                    if kind not in ("worst", "link"):
                        print(summary(kind, values))
                print(f"    largest duty while a stop from rest was confirmed: {got['worst'][0]:g}; since start: "
                      + ", ".join(f"{k} {v}" for k, v in got["link"].items()))
    print(f"load average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    asyncio.run(main())
