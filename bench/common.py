"""What the benchmarks share: a robot config of their own, on a free loopback port, and the CPU
time of processes."""

from __future__ import annotations

import os
import time
from pathlib import Path

from icefloe.testing import free_port

__all__ = ["ROOT", "cmdline", "cpu_percent", "cpu_seconds", "cpu_seconds_with_children", "free_port", "parent_of",
           "read_state", "robot_config", "robot_processes"]

ROOT = Path(__file__).resolve().parent.parent
TICK = os.sysconf("SC_CLK_TCK")
"""Clock ticks per second in /proc/<pid>/stat."""


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process (all its threads) so far, s."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK  # utime, stime: fields 14 and 15 of stat(5)


def cpu_seconds_with_children(pid: int) -> float:
    """`cpu_seconds` of a process and of its children (hwbridge runs its cycle in a child), s."""
    total = 0.0
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(entry.name) == pid or int(fields[1]) == pid:
            total += (int(fields[11]) + int(fields[12])) / TICK
    return total


def cpu_percent(pid: int, seconds: float) -> float:
    """Percent of one core used by process ``pid`` over the next ``seconds`` (this sleeps meanwhile)."""
    c0, t0 = cpu_seconds(pid), time.monotonic()
    time.sleep(seconds)
    c1, t1 = cpu_seconds(pid), time.monotonic()
    return 100.0 * (c1 - c0) / (t1 - t0)


def robot_config(folder: Path, name: str, extra_toml: str = "") -> Path:
    """``folder/<name>.toml``: the simulated robot under its own name, run dir and Zenoh port."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    path = folder / f"{name}.toml"
    path.write_text(f'extends = "{ROOT / "deploy/robots/sim.toml"}"\nname = "{name}"\nrun_dir = "{folder}/run"\n'
                    f'{extra_toml}\n[zenoh]\nlisten = ["{endpoint}"]\nconnect = ["{endpoint}"]\n')
    return path


def read_state(shared) -> dict:  # type: ignore[no-untyped-def]
    """hwbridge's cycle state, read again until no write is in progress (`Shared.read_state`)."""
    while (state := shared.read_state()) is None:
        time.sleep(0.001)
    return state


def cmdline(pid: int) -> list[str]:
    """A process's command line, as words ([] if it is gone). A service the fork server started
    has set its title as one string with spaces between the words."""
    try:
        return (Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode().split())
    except OSError:
        return []


def parent_of(pid: int) -> int:
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, ValueError):
        return 0


def robot_processes(config: Path, runtime_dir: Path | None = None) -> dict[str, list[int]]:
    """Name -> pids of every process of a robot run by `icefloe up` with this config: the launcher,
    each service (by ``-m icefloe.services.<name>``), the router, hwbridge's cycle (its child), and
    the fork server (by its socket in ``runtime_dir``)."""
    out: dict[str, list[int]] = {}
    socket = f"{runtime_dir}/forkserver.sock" if runtime_dir else None
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        words = cmdline(int(entry.name))
        if "-m" not in words:
            continue
        module = words[words.index("-m") + 1]
        if str(config) in words:
            name = "launcher" if module == "icefloe.cli" else module.rsplit(".", 1)[-1]
        elif socket and module == "icefloe.forkserver" and socket in words:
            name = "forkserver"
        elif module == "icefloe.services.hwbridge.rt":
            name = "hwbridge (cycle)"
        else:
            continue
        out.setdefault(name, []).append(int(entry.name))
    bridges = set(out.get("hwbridge", []))
    cycles = [p for p in out.pop("hwbridge (cycle)", []) if parent_of(p) in bridges]  # this robot's only
    if cycles:
        out["hwbridge (cycle)"] = cycles
    return out


PI3B_SLOWER = 6.4
"""How many times longer a Raspberry Pi 3B's core (Cortex-A53, 1.2 GHz) takes than one of the build
machine's for the same single-threaded work: CPython 3.11's float loop of alexdedyura/cpu-benchmark,
published for a Pi 3B+ and scaled by clock (1.4 / 1.2), against the same loop here
(bench/pi_conversion.py; docs/deploy.md, "How much of a Pi 3B the robot leaves to students").
Measured on a busy machine: on a quiet one the same loop gives about twice this, which is why
bench/stack_cpu.py measures its own factor beside each window and uses this one only to place
`PI3B_RANGE` around it."""
PI3B_RANGE = (5.0, 9.4)
"""The range of `PI3B_SLOWER`: sysbench's C (detection is OpenCV's C++, the cycle mostly system
calls) to Salwan's simplebench primes (Python 2.7 on the Pi). docs/deploy.md."""
PI3B_GOALS = {"standing": 0.5, "driving": 1.0}
"""The robot side's goals in Pi 3B cores (issue 35): at rest, and driving with detection on."""
