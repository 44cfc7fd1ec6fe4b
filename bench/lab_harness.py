"""The lab on one machine, for `bench/lab_scale.py` and `tests/test_lab.py`: real processes only.

* `Lab`: a TA's folder of credentials files (one per robot, `icefloe.credentials.make`),
  a lab config, and per robot a config that extends ``deploy/robots/sim.toml`` with its
  own name, run folder, rates and credentials. Either the robot's services connect to the
  lab router, or (``mesh=True``, what docs/lab.md sets up) the robot has its own router
  that joins the lab router. It starts the lab router (``icefloe router lab.toml --lab
  DIR``), each robot's router (mesh) and its ``services.sim``, ``services.hwbridge`` and
  ``services.odometry``, and stops them with SIGINT.
* `CpuMeter`: CPU time of processes over a window, from ``/proc/<pid>/stat``.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
import uuid
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from common import cpu_seconds, free_port

from icefloe import config as config_mod
from icefloe import credentials
from icefloe.config import RobotConfig

ROOT = Path(__file__).resolve().parent.parent
SIM_CONFIG = ROOT / "deploy" / "robots" / "sim.toml"
SERVICES = ("sim", "hwbridge", "odometry")
"""What runs per robot: the simulated board, the bridge to it, and dead reckoning."""


# ---------------------------------------------------------------------------- CPU from /proc


def children(pid: int) -> list[int]:
    """Direct children of a process (hwbridge's real-time cycle is a child of hwbridge)."""
    kids = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):
            kids += [int(k) for k in (task / "children").read_text().split()]
    return kids


def machine_busy() -> tuple[float, float]:
    """(busy, total) jiffies of all CPUs so far, from /proc/stat (includes everyone's processes)."""
    values = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = values[3] + values[4]  # idle + iowait
    total = sum(values[:8])  # guest time is already counted in user
    return total - idle, total


@dataclass
class CpuMeter:
    """CPU use of named groups of processes over a window: `start`, then `stop` -> percent of one core."""

    groups: dict[str, list[int]]
    _t0: float = 0.0
    _c0: dict[int, float] = field(default_factory=dict)
    _m0: tuple[float, float] = (0.0, 0.0)

    def start(self) -> None:
        self._t0, self._m0 = time.monotonic(), machine_busy()
        self._c0 = {pid: cpu_seconds(pid) for pids in self.groups.values() for pid in pids}

    def stop(self) -> tuple[dict[str, float], float]:
        """Percent of one core per group, and the whole machine's busy percent (of all CPUs)."""
        elapsed = time.monotonic() - self._t0
        busy, total = machine_busy()
        out = {}
        for name, pids in self.groups.items():
            used = 0.0
            for pid in pids:
                with contextlib.suppress(OSError):  # a process that died is left out
                    used += cpu_seconds(pid) - self._c0[pid]
            out[name] = 100.0 * used / elapsed
        return out, 100.0 * (busy - self._m0[0]) / max(1.0, total - self._m0[1])


# ---------------------------------------------------------------------------- the lab


@dataclass(frozen=True)
class Rates:
    """The rates each simulated robot runs at (printed with the results)."""

    cycle_hz: float = 250.0
    """hwbridge.rate_hz: the real-time cycle (the robot default is 1000)."""
    serial_hz: float = 100.0
    """hwbridge.serial_rate_hz: PenguinPi exchanges (default 200)."""
    wheels_hz: float = 50.0
    """hwbridge.wheels_rate_hz: hw/wheels on the bus (default 100)."""
    odom_hz: float = 25.0
    """odometry.rate_hz: odom/pose on the bus (default 50)."""


def _wait_listening(router: Proc, timeout: float) -> None:
    """Until the router process says it listens; fails if it exits first or takes too long."""
    deadline = time.monotonic() + timeout
    while "listening on" not in router.log.read_text(errors="replace"):
        if not router.alive() or time.monotonic() > deadline:
            raise RuntimeError(f"{router.name} did not start:\n{router.tail()}")
        time.sleep(0.1)


class Proc:
    """One real process, its output in a log file, in its own process group (hwbridge has a child)."""

    def __init__(self, name: str, args: list[str], log: Path) -> None:
        self.name, self.log = name, log
        with open(log, "wb") as out:
            self.popen = subprocess.Popen(args, stdout=out, stderr=subprocess.STDOUT, cwd=ROOT,
                                          env={**os.environ, "PYTHONUNBUFFERED": "1"},
                                          start_new_session=True)

    @property
    def pid(self) -> int:
        return self.popen.pid

    def alive(self) -> bool:
        return self.popen.poll() is None

    def tail(self, lines: int = 15) -> str:
        return "\n".join(self.log.read_text(errors="replace").splitlines()[-lines:])

    def interrupt(self) -> None:
        if self.alive():
            self.popen.send_signal(signal.SIGINT)

    def wait(self, timeout: float) -> bool:
        """Wait for the exit; after ``timeout`` kill the whole group. True if it exited by itself."""
        try:
            self.popen.wait(timeout)
            return True
        except subprocess.TimeoutExpired:
            print(f"{self.name} did not exit within {timeout:.0f} s of SIGINT: killed", file=sys.stderr)
            os.killpg(self.pid, signal.SIGKILL)
            self.popen.wait()
            return False


class Lab:
    """A lab on this machine: credentials folder, lab router, N robots. Use as a context manager.

    ``mesh=False``: each robot's services are clients of the lab router itself. ``mesh=True``
    (docs/lab.md): each robot has its own router, on its own port, which joins the lab router
    over ``ws`` (``[zenoh] lab``); the robot's services are clients of their own router.
    ``extra_toml(i, name)`` adds TOML to robot ``i``'s config.
    """

    def __init__(self, root: Path, robots: int, rates: Rates = Rates(), *, mesh: bool = False,
                 services: Sequence[str] = SERVICES, extra_toml: Callable[[int, str], str] | None = None) -> None:
        self.root = root
        self.rates = rates
        self.mesh = mesh
        self.services = tuple(services)
        self.port = free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.uplink = f"ws/127.0.0.1:{free_port()}"
        """Where the robots' routers join the lab router (mesh)."""
        # A random tag keeps robot names (and so hwbridge's shared memory) apart from any
        # other lab running on this machine at the same time.
        tag = uuid.uuid4().hex[:4]
        self.names = [f"lab{tag}-{i:02d}" for i in range(robots)]
        self.lab_dir = root / "lab"  # the TA's folder: one credentials file per robot
        self.configs: dict[str, Path] = {}
        self.endpoints: dict[str, str] = {}
        """Per robot, where its services connect: its own router (mesh) or the lab router."""
        self.router: Proc | None = None
        self.procs: dict[str, list[Proc]] = {}
        self.killed: list[str] = []
        """Processes `close` had to kill (a service that ignores SIGINT is a bug)."""
        for i, name in enumerate(self.names):
            self.endpoints[name] = f"tcp/127.0.0.1:{free_port()}" if mesh else self.endpoint
            creds, _ = credentials.make(self.lab_dir / f"{name}.credentials", name, [self.endpoint])
            self.configs[name] = self._robot_config(i, name, creds, extra_toml(i, name) if extra_toml else "")
        self.lab_config = root / "lab.toml"
        listen = [self.endpoint, self.uplink] if mesh else [self.endpoint]
        self.lab_config.write_text(f'name = "lab"\nrun_dir = "{root / "run-lab"}"\n\n'
                                   f"[zenoh]\nlisten = {json.dumps(listen)}\nconnect = []\n")

    def _robot_config(self, i: int, name: str, creds: Path, extra: str) -> Path:
        r = self.rates
        cpus = sorted(os.sched_getaffinity(0))
        path = self.root / f"{name}.toml"
        own = self.endpoints[name]
        zenoh = (f'listen = ["{own}"]\nconnect = ["{own}"]\nlab = ["{self.uplink}"]\n' if self.mesh
                 else f'listen = []\nconnect = ["{own}"]\n')
        path.write_text(
            f'extends = "{SIM_CONFIG}"\nname = "{name}"\nrun_dir = "{self.root / f"run-{name}"}"\n'
            f"services = {json.dumps(list(self.services))}\n\n"
            f"[hwbridge]\nrate_hz = {r.cycle_hz}\nserial_rate_hz = {r.serial_hz}\n"
            f"wheels_rate_hz = {r.wheels_hz}\n"
            # Spread the robots' real-time cycles over the CPUs (a real lab has one Pi each).
            f"cpu = {cpus[i % len(cpus)]}\n\n"
            # The pose at its rate standing too (no 4 Hz heartbeat at rest): lab_scale.py checks every
            # robot's odom/pose against rate_hz, the undriven ones as the driven, as the lab's load.
            f"[odometry]\nrate_hz = {r.odom_hz}\nrest_rate_hz = {r.odom_hz}\n\n"
            f"[sim]\nseed = {i + 1}\ncamera = false\n\n"
            f"{extra}\n\n"
            f"[zenoh]\n{zenoh}access_control = true\ncredentials = \"{creds}\"\n"
        )
        return path

    def config(self, name: str) -> RobotConfig:
        return config_mod.load(self.configs[name])

    def credentials_file(self, name: str) -> Path:
        return self.lab_dir / f"{name}.credentials"

    # -------------------------------------------------------------- processes

    def start_router(self, timeout: float = 20.0) -> Proc:
        """``icefloe router --lab DIR``; returns once it says it listens (fails if it exits)."""
        self.router = Proc("router", [sys.executable, "-m", "icefloe.cli", "router", str(self.lab_config),
                                      "--lab", str(self.lab_dir)],
                           self.root / "router.log")
        _wait_listening(self.router, timeout)
        return self.router

    def start_robots(self, timeout: float = 60.0) -> None:
        """Every robot: first all robots' routers (mesh; all start at once), then their services."""
        if self.mesh:
            routers = [self._start_robot_router(name) for name in self.names]
            for router in routers:
                _wait_listening(router, timeout)
        for name in self.names:
            self._start_services(name, self.services)

    def start_robot(self, name: str, services: Sequence[str] | None = None, timeout: float = 20.0) -> None:
        """The robot's own router (mesh; waits until it listens) and its services' processes."""
        if self.mesh:
            _wait_listening(self._start_robot_router(name), timeout)
        self._start_services(name, self.services if services is None else services)

    def _start_robot_router(self, name: str) -> Proc:
        router = Proc(f"{name}/router", [sys.executable, "-m", "icefloe.router", "--config", str(self.configs[name])],
                      self.root / f"{name}-router.log")
        self.procs.setdefault(name, []).append(router)
        return router

    def _start_services(self, name: str, services: Sequence[str]) -> None:
        self.procs.setdefault(name, []).extend(
            Proc(f"{name}/{service}", [sys.executable, "-m", f"icefloe.services.{service}",
                                       "--config", str(self.configs[name])], self.root / f"{name}-{service}.log")
            for service in services)

    def robot_pids(self) -> dict[str, list[int]]:
        """Robot process ids by service (a robot's router is ``router``), hwbridge's real-time
        child counted as ``hwbridge-rt``."""
        pids: dict[str, list[int]] = defaultdict(list)
        for procs in self.procs.values():
            for proc in procs:
                service = proc.name.split("/")[1].replace("router", "robot router")
                pids[service].append(proc.pid)
                if service == "hwbridge":
                    pids["hwbridge-rt"] += children(proc.pid)
        return dict(pids)

    def cycle_pids(self) -> dict[str, list[int]]:
        """Per robot, the pid of its hwbridge's real-time cycle (hwbridge's child; [] if none now)."""
        out = {}
        for name, procs in self.procs.items():
            hwbridge = next((p for p in procs if p.name.endswith("/hwbridge")), None)
            if hwbridge is None:  # a robot that runs its router only
                continue
            with contextlib.suppress(OSError):  # hwbridge itself has exited
                out[name] = children(hwbridge.pid) if hwbridge.alive() else []
        return out

    def dead(self) -> list[str]:
        """Processes that have exited, with the end of their output."""
        procs = [p for ps in self.procs.values() for p in ps] + ([self.router] if self.router else [])
        return [f"{p.name} exited ({p.popen.returncode}):\n{p.tail()}" for p in procs if not p.alive()]

    def close(self) -> None:
        """SIGINT to every robot's services, then the robots' routers, then the lab router; kill
        what does not stop."""
        services = [p for ps in self.procs.values() for p in ps if not p.name.endswith("/router")]
        routers = [p for ps in self.procs.values() for p in ps if p.name.endswith("/router")]
        if self.router is not None:
            routers.append(self.router)
        for group in (services, routers):
            for proc in group:
                proc.interrupt()
            self.killed += [proc.name for proc in group if not proc.wait(15.0)]

    def __enter__(self) -> Lab:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
