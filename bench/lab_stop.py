"""The lab's emergency stop on a simulated lab: how long each robot takes to confirm `icefloe lab stop`.

Starts a lab on this machine (`lab_harness.Lab`, mesh as docs/lab.md sets it up: the lab router, and
N robots each with its own router joined to it, running ``sim`` and ``hwbridge``), with a TA's
credentials file in the lab's folder. Every robot's owner drives it all along (``cmd/twist`` at 10 Hz
from a session with its credentials on the lab router). Then, ``--rounds`` times:

* ``icefloe lab stop lab.toml --hold``, run as the TA types it (a process: Python's start counts in
  its run time), and ``icefloe lab release``;
* the reference, in the same run: each owner's own ``cmd/halt`` (``rest = false``: answered when the
  board has confirmed the stop, the confirmation a lab stop waits for), all at once, through the same
  lab router, while driving; and the command's run time when it refuses a bad ``--robot`` before
  it opens a session (Python's start and imports alone).

Prints per robot the lab stop's confirmation time (the command's own line: from its request to the
robot's answer) next to the owner's ``cmd/halt`` round trip, and the command's whole run time.

    .venv/bin/python bench/lab_stop.py --robots 3 --rounds 5
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import re
import statistics
import sys
import tempfile
import time
from pathlib import Path

from lab_harness import ROOT, Lab
from lab_scale import laptop_config

from icefloe import credentials
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m

CONFIRMED = re.compile(r"^(\S+): confirmed in (\d+) ms")


async def drive(node: Node) -> None:
    """The owner's program: a gentle circle, ten twists a second, until cancelled."""
    twist = node.publisher(keys.TWIST)
    while True:
        twist.put(node.command(m.Twist, v=0.1, w=0.5))
        await asyncio.sleep(0.1)


async def lab_command(lab: Lab, *args: str) -> tuple[float, dict[str, float], str]:
    """``icefloe lab ARGS lab.toml``: its run time, s; each robot's confirmation, ms; its output."""
    started = time.monotonic()
    proc = await asyncio.create_subprocess_exec(sys.executable, "-m", "icefloe.cli", "lab", *args,
                                                str(lab.lab_config), cwd=ROOT, stdout=asyncio.subprocess.PIPE,
                                                stderr=asyncio.subprocess.STDOUT)
    out, _ = await proc.communicate()
    text = out.decode(errors="replace")
    took = {g[1]: float(g[2]) for line in text.splitlines() if (g := CONFIRMED.match(line))}
    return time.monotonic() - started, took, text


async def halt(node: Node) -> float:
    """The owner's ``cmd/halt`` (rest = false), round trip in ms."""
    started = time.monotonic()
    await node.query(keys.HALT, node.command(m.Halt, rest=False), timeout=10.0)
    return (time.monotonic() - started) * 1e3


async def measure(lab: Lab, rounds: int) -> None:
    async with contextlib.AsyncExitStack() as stack:
        owners = {name: await stack.enter_async_context(
            Node(f"owner-{name}", laptop_config(lab.credentials_file(name), lab.endpoint), announce=False))
            for name in lab.names}
        for node in owners.values():  # hwbridge up: its hw/wheels come
            await asyncio.wait_for(anext(node.subscribe(keys.WHEELS)), 120)
        programs = [asyncio.create_task(drive(node)) for node in owners.values()]
        lab_ms: dict[str, list[float]] = {name: [] for name in lab.names}
        halt_ms: dict[str, list[float]] = {name: [] for name in lab.names}
        runs: list[float] = []
        starts: list[float] = []
        missed: list[str] = []
        for round_ in range(rounds):
            await asyncio.sleep(1.0)  # driving
            took, confirmed, text = await lab_command(lab, "stop", "--hold")
            if round_ == 0:
                print(f"$ icefloe lab stop lab.toml --hold\n{text}", end="")
            runs.append(took)
            for name in lab.names:
                if name in confirmed:
                    lab_ms[name].append(confirmed[name])
                else:
                    missed.append(f"{name}: {text}")
            await lab_command(lab, "release")
            starts.append((await lab_command(lab, "stop", "--robot", "not$*a-robot"))[0])  # refused before a session
            await asyncio.sleep(1.0)  # driving again
            for program in programs:  # the owners' halts: their programs pause (a twist after a halt would
                program.cancel()      # release its stop before the board confirmed it), the wheels still turn
            for name, ms in zip(owners, await asyncio.gather(*(halt(node) for node in owners.values())), strict=True):
                halt_ms[name].append(ms)
            programs = [asyncio.create_task(drive(node)) for node in owners.values()]
        for program in programs:
            program.cancel()
        for node in owners.values():
            node.publisher(keys.STOP).put(node.command(m.Stop))

    print(f"\n{'robot':<12} {'lab stop confirmed, ms':>24} {'owner cmd/halt (ref), ms':>26}")
    print(f"{'':<12} {'median':>12} {'max':>11} {'median':>13} {'max':>12}")
    for name in lab.names:
        lab_s = lab_ms[name] or [float("nan")]
        print(f"{name:<12} {statistics.median(lab_s):12.0f} {max(lab_s):11.0f} "
              f"{statistics.median(halt_ms[name]):13.0f} {max(halt_ms[name]):12.0f}")
    print(f"\n`icefloe lab stop --hold` run time: median {statistics.median(runs):.2f} s, max {max(runs):.2f} s "
          f"over {len(runs)} runs")
    print(f"reference, the same command refusing a bad --robot (Python's start and imports, no session): "
          f"median {statistics.median(starts):.2f} s, max {max(starts):.2f} s")
    print(f"robots not confirmed: {len(missed)}" + "".join(f"\n  {line}" for line in missed))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--robots", type=int, default=3, help="robots in the lab (default 3)")
    parser.add_argument("--rounds", type=int, default=5, help="lab stops (and owners' halts) measured (default 5)")
    parser.add_argument("--timeout", type=float, default=5.0,
                        help="[lab] timeout: how long each robot has to confirm, s (default 5; the lab's default is 1)")
    args = parser.parse_args()
    print(f"$ {' '.join([Path(sys.executable).name, *sys.argv])}")
    print(f"load average before: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    with tempfile.TemporaryDirectory() as tmp, Lab(Path(tmp), args.robots, mesh=True,
                                                   services=("sim", "hwbridge")) as lab:
        ta, _ = credentials.make(lab.lab_dir / "ta.credentials", "*", [lab.endpoint])
        ta.write_text(ta.read_text().replace('user = "*"', 'user = "ta"'))
        with lab.lab_config.open("a") as f:
            f.write(f'\n[lab]\nfolder = "{lab.lab_dir}"\ntimeout = {args.timeout}\n')
        lab.start_router()
        lab.start_robots()
        asyncio.run(measure(lab, args.rounds))
        done = lab.dead()
    print(f"load average after: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    for line in done:
        print(f"FAIL {line}")
    return 1 if done else 0


if __name__ == "__main__":
    sys.exit(main())
