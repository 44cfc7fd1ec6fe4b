"""How much slower a Raspberry Pi's core runs what the robot runs: published single-core figures of a
Raspberry Pi 3B+ and a Pi 4, next to the same workloads measured here, in this run.

    .venv/bin/python bench/pi_conversion.py [--repeat 3] [--fraction 0.1]

No Pi is at hand, and emulation says nothing about timing, so the factors that
`bench/stack_cpu.py` converts with (docs/deploy.md, "How much of a Pi 3B the robot
leaves to students") come from workloads someone ran on a Pi and published, run here
too. Each workload below is written from its published description (the operations,
their order and scope), not copied; each published figure names its page.

* ``float loop``: the Python loop of alexdedyura/cpu-benchmark, at module level as there
  (every name a global): 10 000 rounds of ``3.141592 * 2**x`` for x in 1..999, then
  ``float(x) / 3.141592`` and ``float(3.141592) / x`` for x in 1..9 999 each. Published
  for a Pi 3B+ with **Python 3.11.2** (the same minor version as here) and a Pi 4.
* ``primes``: Salwan's simplebench, at module level: the primes below 100 000 by trial
  division up to the square root, dividing as floats. Published for a Pi 3 and a Pi 4 with
  **Python 2.7**: a different interpreter from this one, so the factor against this machine
  is a cross-check only; the Pi 3 / Pi 4 ratio on the same page is not touched by it. The page
  lists its Pi 3 as "Cortex A53 1.2GHz" (a 3B) and its table row as "Cortex A53 1.4GHz" (a
  3B+): taken here as a 3B+, which makes the scaled 3B factor the higher of the two readings.
* ``sysbench cpu`` (C; primes to 10 000, one thread), when ``sysbench`` is installed
  (Debian's ``sysbench``): published for a Pi 3B+ and a Pi 4 with sysbench 1.0.20. Its
  inner loop is integer division, which says nothing about an interpreter: a floor.

Times here are CPU time of this process (``time.process_time``; sysbench's from
``getrusage`` of the child), the best of ``--repeat`` runs, so that a busy machine's waiting is
not counted. A Raspberry Pi 3B runs the same Cortex-A53 core as the 3B+ at 1.2 GHz instead of
1.4 GHz, so a 3B+ factor is scaled by 1.4 / 1.2 for the 3B (the 3B+ itself drops to 1.2 GHz
above 60 °C, its soft limit: the published figures may be partly at 1.2 GHz, which would make
the scaled 3B factor a little high).
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import subprocess
import sys
import time

PI3B_CLOCK_SCALE = 1.4 / 1.2
"""A Pi 3B+ figure (Cortex-A53 at 1.4 GHz) -> a Pi 3B (the same core at 1.2 GHz)."""

FLOAT_LOOP_ROUNDS = 10_000
FLOAT_LOOP = """
for _round in range(ROUNDS):
    for x in range(1, 1000):
        3.141592 * 2**x
    for x in range(1, 10000):
        float(x) / 3.141592
    for x in range(1, 10000):
        float(3.141592) / x
"""
"""alexdedyura/cpu-benchmark's attempt, ``ROUNDS`` = 10 000 (run at module level, as there)."""

PRIMES = """
found = []
composite = False
for i in range(2, 100000):
    composite = False
    limit = math.floor(math.sqrt(float(i))) + 1.0
    for j in range(2, int(limit)):
        quotient = i / float(j)
        whole = int(quotient)
        if quotient == whole:
            composite = True
            break
    if composite:
        continue
    found.append(i)
assert len(found) == 9592
"""
"""Salwan's simplebench: the primes below 100 000 (run at module level, as there)."""

PUBLISHED = {
    # workload: [(machine, seconds or events/s, what and where)]
    "float loop": [
        ("Pi 3B+", 245.0, "average of 10 attempts, Python 3.11.2, Raspberry Pi OS (kernel 6.6.20+rpt-rpi-v8): "
                          "https://github.com/alexdedyura/cpu-benchmark/issues/20"),
        ("Pi 4", 79.216, "average of 10 attempts, Ubuntu 22.04.3 (its Python, 3.10): "
                         "https://github.com/alexdedyura/cpu-benchmark (README, results table)"),
    ],
    "primes": [
        ("Pi 3B+", 10.22, "best of 10+, Python 2.7, Raspbian, table row 'Cortex A53 1.4GHz': "
                          "https://github.com/Salwan/salwan.github.io/blob/master/_posts/2019-10-03-simplebench.md"),
        ("Pi 4", 4.3, "best of 10+, Python 2.7, Raspbian: the same page"),
    ],
    "sysbench cpu": [
        ("Pi 3B+", 687.45, "events/s, --threads=1, sysbench 1.0.20: https://leoncode.co.uk/articles/raspberry-pi-benchmarks"),
        ("Pi 4", 1477.83, "events/s, the same page"),
    ],
}


def cpu_time_of(source: str, **names: object) -> float:
    """CPU seconds to run ``source`` as a module's top level (its names globals, as in the originals)."""
    code = compile(source, "<workload>", "exec")
    scope: dict[str, object] = {"__name__": "__workload__", **names}
    start = time.process_time()
    exec(code, scope)  # our own workload text, above
    return time.process_time() - start


def float_loop(fraction: float) -> float:
    """CPU seconds of one published attempt (10 000 rounds), from ``fraction`` of it."""
    rounds = max(1, round(FLOAT_LOOP_ROUNDS * fraction))
    return cpu_time_of(FLOAT_LOOP, ROUNDS=rounds) * FLOAT_LOOP_ROUNDS / rounds


def primes() -> float:
    import math

    return cpu_time_of(PRIMES, math=math)


def sysbench_events_per_cpu_s(events: int = 4000) -> float | None:
    """sysbench cpu, one thread: events per CPU-second of the child (None without sysbench)."""
    exe = shutil.which("sysbench")
    if exe is None:
        return None
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = subprocess.run([exe, "cpu", "--threads=1", f"--events={events}", "--time=0", "run"],
                         capture_output=True, text=True, check=True).stdout
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = int(re.search(r"total number of events:\s+(\d+)", out).group(1))  # type: ignore[union-attr]
    used = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return done / used


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeat", type=int, default=3, help="runs of each workload; the best counts")
    p.add_argument("--fraction", type=float, default=0.1,
                   help="part of the float loop's attempt to run (its time is per round: scaled up)")
    args = p.parse_args()
    load = os.getloadavg()[0]
    here: dict[str, float] = {}
    here["float loop"] = min(float_loop(args.fraction) for _ in range(args.repeat))
    here["primes"] = min(primes() for _ in range(args.repeat))
    rates = [r for r in (sysbench_events_per_cpu_s() for _ in range(args.repeat)) if r is not None]
    if rates:
        here["sysbench cpu"] = max(rates)
    print(f"this machine: Python {sys.version.split()[0]}, {os.cpu_count()} cores, load average {load:.1f} at the "
          f"start, {os.getloadavg()[0]:.1f} at the end; best of {args.repeat}, CPU time")
    print(f"{'workload':<13} {'here':>10} {'Pi 3B+':>10} {'Pi 4':>10}   Pi 3B+ / here  -> Pi 3B   Pi 4 / here"
          "   Pi 3B+ / Pi 4")
    for name, figures in PUBLISHED.items():
        if name not in here:
            print(f"{name:<13} {'(not installed here)':>10}")
            continue
        pi3, pi4 = figures[0][1], figures[1][1]
        rate = name == "sysbench cpu"  # events/s: higher is faster
        unit = "/s" if rate else " s"
        slower3 = here[name] / pi3 if rate else pi3 / here[name]
        slower4 = here[name] / pi4 if rate else pi4 / here[name]
        print(f"{name:<13} {here[name]:8.2f}{unit} {pi3:8.2f}{unit} {pi4:8.2f}{unit}   {slower3:10.2f}x  "
              f"{slower3 * PI3B_CLOCK_SCALE:7.2f}x  {slower4:10.2f}x   {slower3 / slower4:12.2f}x")
    print("sources:")
    for name, figures in PUBLISHED.items():
        for machine, value, where in figures:
            print(f"  {name}, {machine}: {value:g} ({where})")


if __name__ == "__main__":
    main()
