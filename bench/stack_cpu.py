"""CPU of every process of the simulated robot while the whole stack runs.

    .venv/bin/python bench/stack_cpu.py [--seconds 20] [--drive]

Starts `icefloe up` on the default simulated robot (on a free port), waits until
every service is alive, optionally drives it in a circle, then reads each
process's CPU time from /proc over the window. In simulation the camera's
frames are rendered by the camera service (`camera.source = "sim"`), so
"simulator with its camera" is the sim process plus the camera process.
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

from common import free_port, robot_config

ROOT = Path(__file__).resolve().parent.parent
TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS  # utime + stime


def children(config: Path) -> dict[str, list[int]]:
    """Service name -> pids, from the command lines naming this config."""
    out: dict[str, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmd = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        text = [c.decode() for c in cmd]
        if str(config) in text and "-m" in text:
            module = text[text.index("-m") + 1]
            name = module.rsplit(".", 1)[-1] if module != "icefloe.cli" else "launcher"
            out.setdefault(name, []).append(int(entry.name))
    for pid in out.get("hwbridge", [])[:]:  # its real-time cycle runs in a child process
        cycle = child_pids(pid)
        if cycle:
            out["hwbridge (cycle)"] = cycle
    return out


def child_pids(parent: int) -> list[int]:
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int(Path(entry, "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError):
                continue
            if ppid == parent:
                pids.append(int(entry.name))
    return pids


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--drive", action="store_true", help="drive in a circle during the window")
    args = p.parse_args()
    config = robot_config(Path(tempfile.mkdtemp()), "cpubench", f"[webapi]\nport = {free_port()}\n")
    icefloe = [sys.executable, "-m", "icefloe.cli"]
    up = subprocess.Popen([*icefloe, "up", str(config), "--no-viz"], stdout=subprocess.DEVNULL,
                          stderr=subprocess.DEVNULL, start_new_session=True)
    driver = None
    try:
        time.sleep(12.0)  # every service up and settled
        if args.drive:
            driver = subprocess.Popen([*icefloe, "pub", "cmd/twist", '{"v": 0.15, "w": 0.5}', "--rate", "10",
                                       "--config", str(config)], stdout=subprocess.DEVNULL)
            time.sleep(2.0)
        procs = children(config)
        before = {n: sum(cpu_seconds(p) for p in pids) for n, pids in procs.items()}
        t0 = time.monotonic()
        time.sleep(args.seconds)
        wall = time.monotonic() - t0
        after = {n: sum(cpu_seconds(p) for p in pids) for n, pids in procs.items()}
    finally:
        if driver is not None:
            driver.terminate()
        up.send_signal(signal.SIGINT)
        up.wait(60)
    usage = {n: 100 * (after[n] - before[n]) / wall for n in procs}
    print(f"CPU over {wall:.0f} s, % of one core ({os.cpu_count()} cores), robot "
          f"{'driving' if args.drive else 'standing'}:")
    for name in sorted(usage, key=usage.get, reverse=True):
        print(f"  {name:<18} {usage[name]:6.1f} %")
    sim, cam = usage.get("sim", 0.0), usage.get("camera", 0.0)
    print(f"  {'all':<18} {sum(usage.values()):6.1f} %")
    print(f"simulator alone {sim:.1f} % (goal < 25 %); simulator with its camera at 15 fps "
          f"{sim + cam:.1f} % (goal < 60 %)")


if __name__ == "__main__":
    main()
