"""Benchmark: from a stop to standstill, on both simulated boards, through the real stack.

    .venv/bin/python bench/stops.py                 # 20 stops per board, from 0.2 m/s
    .venv/bin/python bench/stops.py --stops 5 --speed 0.3

What runs: the robot's router, the simulator and hwbridge as processes, for the
PenguinPi (firmware model on a pseudo-terminal) and the icoBoard v2 (model on its
socket). A client drives at ``--speed`` for 1 s, then stops with `Robot.stop`
(``cmd/stop``, then ``cmd/halt`` with ``rest = false`` for the same stop: it returns
when hwbridge has confirmed the stop). Meanwhile it reads the simulator's truth as
fast as it answers (``sim/control``: duty, true encoder counts, the firmware's
integrators, in simulated time).

Per board it prints, over the stops:

* stop -> confirmed: wall time of `Robot.stop` (publish, hwbridge, board, reply);
* stop -> zero duty on the board (simulated time: ``SimState.zero_duty_since``),
  and whether the integrators were 0 at the confirmation;
* stop -> standstill: the last change of the true encoder counts (simulated time:
  ``counts_changed``; the wheels coast with duty 0, the motor model's time
  constant is 0.1 s), and the distance coasted;
* the largest duty from the confirmation on (must be 0), and the counts in the
  second after standstill (the motor model slows exponentially, with no
  stiction, so a last count can come late).

The reference, in the same run: the firmware model alone, stopped as before this
change (MULTI_ALL_STOP: demand 0, integral gain left at 1), from the same speed:
its duty and integrator 2 s later and how far it crept. The stop's instant is
mapped onto the simulator's clock from one reading (wall stamp, simulated time)
just before it: on a loaded machine, where the simulator falls behind, the
simulated-time durations can come out a few ms short.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import robot_config

from icefloe import config as config_mod
from icefloe.client import AsyncRobot
from icefloe.config import Geometry
from icefloe.errors import NotConfirmed
from icefloe.schemas import keys
from icefloe.schemas import messages as m

ROOT = Path(__file__).resolve().parent.parent
BOARDS = {"penguinpi": "", "icoboard-v2": '[board]\nkind = "icoboard"\nbackend = "sim"\nprotocol = 2\n'}


async def one_stop(robot: AsyncRobot, speed: float) -> dict[str, float]:
    node = robot.node

    async def truth() -> m.SimState:
        return await node.query(keys.SIM_CONTROL, m.SimControl(), timeout=5.0)

    await robot.set_velocity(speed, speed)
    await asyncio.sleep(1.0)
    before = await truth()
    issued = time.time_ns()
    started = time.monotonic()
    try:
        await robot.stop()  # returns once hwbridge has confirmed the stop
    except NotConfirmed as exc:  # e.g. the simulator so starved that the board link dropped
        print(f"  not confirmed: {exc}")
        await asyncio.sleep(3.0)
        return {"driving": 0.0, "peak_duty_after": 0.0, "unconfirmed": 1.0}
    confirmed = time.monotonic() - started
    at_confirmation = await node.query(keys.SIM_CONTROL, m.SimControl(action="mark"), timeout=5.0)
    while (s := await truth()).sim_time - s.counts_changed < 0.5:  # until still for 0.5 s
        await asyncio.sleep(0.05)
    await asyncio.sleep(1.0)
    after = await truth()
    # The stop's instant on the simulator's clock (which keeps pace with the wall clock).
    stop = before.sim_time + (issued - before.stamp) * 1e-9
    k = math.pi * robot.config.geometry.wheel_diameter / robot.config.geometry.ticks_per_rev
    return {
        "confirmed_ms": confirmed * 1e3,
        "zero_ms": (s.zero_duty_since - stop) * 1e3,
        "driving": float(before.duty_left != 0.0),
        "integrators_clear": float(at_confirmation.integrator_left == at_confirmation.integrator_right
                                   == 0),
        "peak_duty_after": after.peak_duty,
        "standstill_ms": (s.counts_changed - stop) * 1e3,
        "coast_mm": (s.ticks_left - before.ticks_left) * k * 1e3,
        "creep_counts": abs(after.ticks_left - s.ticks_left) + abs(after.ticks_right - s.ticks_right),
    }


async def board_run(config_path: Path, stops: int,
                    speed: float) -> tuple[list[dict[str, float]], m.LoopStats]:
    config = config_mod.load(config_path)
    procs = [subprocess.Popen([sys.executable, "-m", module, "--config", str(config_path)],
                              cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True)
             for module in ("icefloe.router", "icefloe.services.sim", "icefloe.services.hwbridge")]
    try:
        robot = AsyncRobot(config=config, timeout=10.0)
        await robot.open(connect_timeout=30)
        try:
            await robot.ready(keys.WHEELS.name, timeout=30)
            results = [await one_stop(robot, speed) for _ in range(stops)]
            loops = robot.node.subscribe(keys.LOOP)
            return results, await asyncio.wait_for(anext(loops), 10)
        finally:
            await robot.close()
    finally:
        for p in reversed(procs):
            p.terminate()
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(10)


def reference(speed: float) -> tuple[int, float, float]:
    """The firmware model alone, stopped with MULTI_ALL_STOP only: (integrator 2 s later,
    duty then, mm crept in those 2 s after the wheels first came to rest)."""
    from icefloe.services.hwbridge.control import speed_to_demand
    from icefloe.sim.penguinpi_firmware import PenguinPiFirmware
    from icefloe.sim.world import World
    from icefloe.wire import penguinpi as ppi

    geometry = Geometry()
    world = World(geometry, seed=1)
    fw = PenguinPiFirmware(world)
    demand = speed_to_demand(speed, geometry)
    fw.receive(ppi.encode_frame(ppi.Address.AD_MULTI, ppi.MultiOp.MULTI_SET_VEL,
                                ppi.pack_multi_set(demand, demand)), 0.0)
    ms = 0

    def run(seconds: float) -> None:
        nonlocal ms
        for _ in range(round(seconds * 1000)):
            ms += 1
            world.step(0.001)
            fw.tick(ms * 1e-3)

    run(1.0)
    fw.receive(ppi.encode_frame(ppi.Address.AD_MULTI, ppi.MultiOp.MULTI_ALL_STOP), 1.0)
    run(0.5)  # it comes to rest (and overshoots back)
    rest = world.pose[0]
    run(2.0)
    return fw.left.integral, world.duty[0], (world.pose[0] - rest) * 1e3


def summary(name: str, values: list[float], unit: str) -> str:
    if not values:
        return f"  {name:<24} (none)"
    values = sorted(values)
    return (f"  {name:<24} p50 {statistics.median(values):7.1f}   max {values[-1]:7.1f}   "
            f"min {values[0]:7.1f}  {unit}")


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--stops", type=int, default=20, help="stops per board")
    parser.add_argument("--speed", type=float, default=0.2, help="speed before each stop, m/s")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for board, toml in BOARDS.items():
            folder = Path(tmp) / board
            folder.mkdir()
            every, stats = await board_run(
                robot_config(folder, f"stops{board.replace('-', '')}", toml), args.stops, args.speed)
            results = [r for r in every if r["driving"]]
            unconfirmed = sum(int(r.get("unconfirmed", 0)) for r in every)
            print(f"{board}: {len(results)} stops from {args.speed} m/s ({len(every) - len(results)} "
                  f"more: {unconfirmed} not confirmed, the others found the wheels not driven; hw/loop: "
                  f"{stats.commands_dropped} commands refused, {stats.timeouts} board timeouts, "
                  f"{stats.late} late replies)")
            print(summary("stop -> confirmed (wall)", [r["confirmed_ms"] for r in results], "ms"))
            print(summary("stop -> zero duty", [r["zero_ms"] for r in results], "ms"))
            print(summary("stop -> standstill", [r["standstill_ms"] for r in results], "ms"))
            print(summary("coasted", [r["coast_mm"] for r in results], "mm"))
            clear = sum(int(r["integrators_clear"]) for r in results)
            creep = sum(int(r["creep_counts"]) for r in results)
            peak = max(r["peak_duty_after"] for r in every)
            print(f"  integrators clear at the confirmation: {clear}/{len(results)};  largest duty "
                  f"from the confirmation on: {peak:g};  counts in the second after standstill: "
                  f"{creep} in total (the motor model's exponential tail)")
    integral, duty, crept = reference(args.speed)
    print(f"reference, the firmware stopped with MULTI_ALL_STOP only: integrator {integral}, duty "
          f"{duty * 100:.1f} % 2.5 s after the stop, {crept:+.1f} mm crept after coming to rest")


if __name__ == "__main__":
    asyncio.run(main())
