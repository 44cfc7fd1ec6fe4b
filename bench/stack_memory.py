"""Memory of every process of the simulated robot, at the start and after driving, against the goal.

    .venv/bin/python bench/stack_memory.py [--seconds 600] [--warmup 120] [--no-fork-server]

Starts `icefloe up` on the default simulated robot (camera detection on; on a free port, no
viewer), waits until every process runs and has settled, and reads each one's proportional set
size (PSS: its private pages, and its share of every page it shares with others) and its private
memory from ``/proc/<pid>/smaps_rollup``, standing. Then it drives the robot in a circle
(``icefloe pub`` at 10 Hz) for ``--warmup`` (what a process allocates once, when it first has
work, is behind it: the camera's encoder, the simulator's textures) and reads them again, then
drives on for ``--seconds`` and reads them a last time. It prints the readings next to a
reference measured in the same run: a bare Python with a Zenoh session, as a service would be
with nothing else.

The robot side is what a robot runs: every process but the launcher (`icefloe up`; a robot runs
its units under systemd) and the simulator. In simulation the camera service renders its own
frames; the renderer's memory (the world, its textures and buffers: the simulator's, not the
robot's) is measured in a process of its own in the same run, over the same drive, and shown
apart, as bench/stack_cpu.py does for its CPU.

It exits 1, naming why, when a process it expects is missing (the cycle first), when the robot
side is over `GOAL_MIB` in any reading, or when a process grew by more than `GROWTH_MIB` from the
second reading to the last.
docs/deploy.md, "Memory", has the figures and what each step bought.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import free_port, robot_config, robot_processes

from icefloe import config as config_mod

GOAL_MIB = 200.0
"""The robot side's PSS with camera detection on (issue 35: what a Raspberry Pi 3B can spare)."""
GROWTH_MIB = 4.0
"""A process whose PSS grows by more than this while driving is growing (a leak, a cache)."""
EXPECTED = ["hwbridge (cycle)", "forkserver", "router", "info", "hwbridge", "odometry", "localizer", "camera",
            "power", "oled", "webapi"]
"""The robot side's processes (the default robot's services, the router, the cycle, the fork server)."""
NOT_THE_ROBOTS = ("launcher", "sim")
RENDERER = """
import sys
from pathlib import Path
def private():
    d = {l.split(":")[0]: int(l.split()[1]) for l in Path("/proc/self/smaps_rollup").read_text().splitlines()[1:]}
    return (d["Private_Dirty"] + d["Private_Clean"]) / 1024
from icefloe import config
from icefloe.services.camera.sources import SimSource
import cv2, numpy
import math
cfg = config.load(sys.argv[1])
before = private()
source = SimSource(cfg)
# the drive below (0.15 m/s, 0.5 rad/s: a circle of 0.3 m from the start pose), twice round at the
# camera's rate: what the renderer caches (each marker's texture at each size it is seen) is all there
v, w, fps = 0.15, 0.5, cfg.camera.fps
for i in range(int(2 * 2 * math.pi / w * fps)):
    t = i / fps
    source.renderer.render(v / w * math.sin(w * t), v / w * (1 - math.cos(w * t)), w * t)
print(private() - before)
"""
REFERENCE = """
import time, zenoh
from pathlib import Path
s = zenoh.open(zenoh.Config())
time.sleep(2)
d = {l.split(":")[0]: int(l.split()[1]) for l in Path("/proc/self/smaps_rollup").read_text().splitlines()[1:]}
print(d["Pss"] / 1024, (d["Private_Dirty"] + d["Private_Clean"]) / 1024)
s.close()
"""


def memory(pid: int) -> tuple[float, float]:
    """(PSS, private) of a process, MiB."""
    fields = {}
    for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines()[1:]:
        key, value = line.split(":", 1)
        fields[key] = int(value.split()[0])
    return fields["Pss"] / 1024, (fields["Private_Dirty"] + fields["Private_Clean"]) / 1024


def snapshot(procs: dict[str, list[int]]) -> dict[str, tuple[float, float]]:
    out = {}
    for name, pids in procs.items():
        pss = private = 0.0
        for pid in pids:
            try:
                a, b = memory(pid)
            except OSError:
                continue
            pss, private = pss + a, private + b
        out[name] = (pss, private)
    return out


def wait_for(config: Path, run_dir: Path, wanted: set[str], timeout: float) -> dict[str, list[int]]:
    deadline = time.monotonic() + timeout
    while not wanted <= set(procs := robot_processes(config, run_dir)):
        if time.monotonic() > deadline:
            missing = sorted(wanted - set(procs), key=lambda n: n != "hwbridge (cycle)")
            raise SystemExit(f"not running after {timeout:.0f} s: {', '.join(missing)}")
        time.sleep(1.0)
    return procs


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=600.0, help="how long to drive between the last two readings, s")
    p.add_argument("--warmup", type=float, default=120.0, help="how long to drive before the second reading, s")
    p.add_argument("--settle", type=float, default=20.0, help="wait this long once every process runs, s")
    p.add_argument("--no-fork-server", action="store_true", help="every service a fresh Python (to compare)")
    args = p.parse_args()
    folder = Path(tempfile.mkdtemp())
    config = robot_config(folder, "membench", f"[webapi]\nport = {free_port()}\n")
    run_dir = config_mod.load(str(config)).runtime_dir
    icefloe = [sys.executable, "-m", "icefloe.cli"]
    expected = [n for n in EXPECTED if not (args.no_fork_server and n == "forkserver")]
    reference = [float(v) for v in subprocess.run([sys.executable, "-c", REFERENCE], capture_output=True,
                                                  text=True, check=True).stdout.split()]
    renderer = float(subprocess.run([sys.executable, "-c", RENDERER, str(config)], capture_output=True, text=True,
                                    check=True).stdout)
    up = subprocess.Popen([*icefloe, "up", str(config), "--no-viz",
                           *(["--no-fork-server"] if args.no_fork_server else [])],
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    driver = None
    try:
        procs = wait_for(config, run_dir, set(expected) | {"sim"}, timeout=180.0)
        time.sleep(args.settle)
        procs = robot_processes(config, run_dir)
        standing = snapshot(procs)
        driver = subprocess.Popen([*icefloe, "pub", "cmd/twist", '{"v": 0.15, "w": 0.5}', "--rate", "10",
                                   "--config", str(config)], stdout=subprocess.DEVNULL)
        time.sleep(args.warmup)
        start = snapshot(procs)
        time.sleep(args.seconds)
        missing = [n for n in expected if n not in robot_processes(config, run_dir)]
        if missing:
            raise SystemExit(f"gone while driving: {', '.join(missing)}")
        end = snapshot(procs)
    finally:
        if driver is not None:
            driver.terminate()
        os.killpg(up.pid, signal.SIGINT)
        up.wait(60)

    for reading in (standing, start, end):
        pss, private = reading["camera"]
        reading["sim (camera renderer)"] = (renderer, renderer)
        reading["camera"] = (pss - renderer, private - renderer)
    mode = "each service a fresh Python" if args.no_fork_server else "services forked from the fork server"
    print(f"Memory of the simulated robot ({mode}), MiB: standing, after driving {args.warmup:.0f} s, "
          f"and after {args.seconds:.0f} s more")
    print(f"  reference, same run: a bare Python with a Zenoh session: PSS {reference[0]:.1f}, "
          f"private {reference[1]:.1f}")
    print(f"  {'':<22} {'PSS':>8} {'driving':>8} {'then':>7}   {'private':>8} {'driving':>8} {'then':>7}")
    order = sorted(end, key=lambda n: (n in NOT_THE_ROBOTS or n.startswith("sim"), -end[n][0]))
    problems = []
    for name in order:
        (p0, v0), (p1, v1), (p2, v2) = (standing.get(name, (0.0, 0.0)), start.get(name, (0.0, 0.0)), end[name])
        note = "  (not the robot's)" if name in NOT_THE_ROBOTS or name.startswith("sim") else ""
        if not note and p2 - p1 > GROWTH_MIB:
            note = f"  GROWING (+{p2 - p1:.1f})"
            problems.append(f"{name} grew {p2 - p1:.1f} MiB in {args.seconds:.0f} s of driving")
        print(f"  {name:<22} {p0:8.1f} {p1:8.1f} {p2:7.1f}   {v0:8.1f} {v1:8.1f} {v2:7.1f}{note}")
    for label, reading in (("standing", standing), (f"after driving {args.warmup:.0f} s", start),
                           (f"after {args.seconds:.0f} s more", end)):
        robot = [v for n, v in reading.items() if n not in NOT_THE_ROBOTS and not n.startswith("sim")]
        pss, private = sum(v[0] for v in robot), sum(v[1] for v in robot)
        over = pss > GOAL_MIB
        print(f"robot side {label}: PSS {pss:.1f} MiB (goal {GOAL_MIB:.0f}{', OVER' if over else ''}), "
              f"private {private:.1f} MiB, {len(robot)} processes")
        if over:
            problems.append(f"the robot side {label} is {pss:.1f} MiB PSS, over {GOAL_MIB:.0f}")
    if problems:
        print("; ".join(problems))
        raise SystemExit(1)


if __name__ == "__main__":
    main()
