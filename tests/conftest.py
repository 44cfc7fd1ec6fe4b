"""Shared fixtures: a fresh robot per test, with its own Zenoh router, name, port and run dir.

    async def test_something(robot):
        hw = robot.start("hwbridge")               # a real process, stopped with SIGINT at the end
        async with robot.node("tester") as node:   # a real Zenoh session in this process
            ...

    def test_icoboard(make_robot):
        robot = make_robot('[board]\\nkind = "icoboard"\\n')   # extra TOML over deploy/robots/sim.toml
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from signal import SIGINT, SIGKILL

import pytest

from icefloe import config as config_mod
from icefloe.config import RobotConfig
from icefloe.deploy import SERVICE_ENV
from icefloe.runtime import Node
from icefloe.testing import free_port

ROOT = Path(__file__).resolve().parent.parent
SIM_CONFIG = ROOT / "deploy" / "robots" / "sim.toml"

# A suite started in the background of a script (`./tests/run.sh &`, `nohup ... &`) inherits
# SIGINT *ignored*, and so would every program it starts: a Ctrl-C sent to `icefloe echo` or to a
# student's script would do nothing, and the tests of Ctrl-C would fail for the harness's sake.
# A Python handler (unlike SIG_IGN) is reset to the default on exec: the programs get a real Ctrl-C.
if signal.getsignal(SIGINT) is signal.SIG_IGN:
    signal.signal(SIGINT, signal.default_int_handler)


def robot_config(folder: Path, name: str, extra_toml: str = "") -> Path:
    """A robot config on a free port with no router started (for tests of `icefloe up` itself)."""
    port = free_port()
    path = folder / f"{name}.toml"
    path.write_text(
        f'extends = "{SIM_CONFIG}"\nname = "{name}{port}"\nrun_dir = "{folder}/run-{name}"\n{extra_toml}\n'
        f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\nconnect = ["tcp/127.0.0.1:{port}"]\n'
    )
    return path


class Proc:
    """A service running as a real process; its output goes to a log file in the test's tmp dir."""

    def __init__(self, name: str, args: list[str], log_path: Path, env: dict[str, str]) -> None:
        self.name = name
        self.log_path = log_path
        self._log = open(log_path, "wb")  # noqa: SIM115 - closed in stop()
        self.popen = subprocess.Popen(args, stdout=self._log, stderr=subprocess.STDOUT, env=env,
                                      cwd=ROOT, start_new_session=True)

    @property
    def output(self) -> str:
        return self.log_path.read_text(errors="replace")

    def alive(self) -> bool:
        return self.popen.poll() is None

    def signal(self, sig: int) -> None:
        if self.alive():
            self.popen.send_signal(sig)

    def stop(self, sig: int = SIGINT, timeout: float = 10.0) -> int:
        """Send ``sig`` and wait; returns the exit code. Kills (and fails) if it does not exit."""
        self.signal(sig)
        try:
            code = self.popen.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(self.popen.pid, SIGKILL)
            self.popen.wait()
            self._log.close()
            raise AssertionError(f"{self.name} did not exit within {timeout} s of {sig!r}:\n{self.output}") from None
        self._log.close()
        return code


class Robot:
    """A test robot: a config file, its router, and the processes a test started."""

    def __init__(self, tmp: Path, extra_toml: str = "", base: Path = SIM_CONFIG,
                 access_control: bool = False) -> None:
        self.tmp = tmp
        self.port = free_port()
        self.name = f"t{uuid.uuid4().hex[:8]}"
        run_dir = tmp / "run"
        run_dir.mkdir(exist_ok=True)
        endpoint = f"tcp/127.0.0.1:{self.port}"
        self.config_path = tmp / f"{self.name}.toml"
        self.credentials_path = tmp / f"{self.name}.credentials"
        zenoh_extra = ""
        if access_control:  # as deploy/up.sh does: credentials first, then the guarded router
            from icefloe.credentials import make

            make(self.credentials_path, self.name, [endpoint])
            zenoh_extra = f'access_control = true\ncredentials = "{self.credentials_path}"\n'
        self.config_path.write_text(
            f'extends = "{base}"\nname = "{self.name}"\nrun_dir = "{run_dir}"\n'
            f"{extra_toml}\n\n[zenoh]\nlisten = [\"{endpoint}\"]\nconnect = [\"{endpoint}\"]\n{zenoh_extra}"
        )
        self.config: RobotConfig = config_mod.load(self.config_path)
        self.procs: list[Proc] = []
        self.env = {**os.environ, **SERVICE_ENV}  # as systemd and `icefloe up` start them
        self.router = self.start_module("icefloe.router", name="router")
        _wait_port(self.port, self.router)

    def start_module(self, module: str, *args: str, name: str | None = None) -> Proc:
        name = name or module.rsplit(".", 1)[-1]
        cmd = [sys.executable, "-m", module, "--config", str(self.config_path), *args]
        proc = Proc(name, cmd, self.tmp / f"{name}-{len(self.procs)}.log", self.env)
        self.procs.append(proc)
        return proc

    def start(self, service: str, *args: str) -> Proc:
        """Start ``icefloe.services.<service>`` as a process against this robot."""
        return self.start_module(f"icefloe.services.{service}", *args, name=service)

    def node(self, service: str = "tester") -> Node:
        return Node(service, self.config)

    def close(self) -> None:
        for proc in reversed(self.procs):
            with contextlib.suppress(AssertionError):
                proc.stop()


def stop_up(up: subprocess.Popen) -> int:
    """Ctrl-C to an `icefloe up` started with ``start_new_session``; its exit status. One that is
    still there after 60 s is killed with its whole process group, and the test fails."""
    up.send_signal(SIGINT)
    try:
        return up.wait(60)
    except subprocess.TimeoutExpired:
        os.killpg(up.pid, SIGKILL)
        raise


def processes_naming(text: str) -> list[int]:
    """PIDs of every process (but this one) whose command line contains ``text``, e.g. a config path."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and int(entry.name) != os.getpid():
            try:
                cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            except OSError:
                continue
            if text in cmd:
                pids.append(int(entry.name))
    return pids


def _wait_port(port: int, proc: Proc, timeout: float = 15.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not proc.alive():
            raise AssertionError(f"router exited:\n{proc.output}")
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    raise AssertionError(f"router did not listen on {port}:\n{proc.output}")


@pytest.fixture
def make_robot(tmp_path: Path) -> Iterator[Callable[..., Robot]]:
    robots: list[Robot] = []

    def make(extra_toml: str = "", base: Path = SIM_CONFIG, access_control: bool = False) -> Robot:
        sub = tmp_path / f"robot{len(robots)}"
        sub.mkdir()
        robots.append(Robot(sub, extra_toml, base, access_control))
        return robots[-1]

    yield make
    for r in robots:
        r.close()


@pytest.fixture
def robot(make_robot: Callable[..., Robot]) -> Robot:
    return make_robot()


async def wait_for(predicate: Callable[[], object], timeout: float = 10.0, interval: float = 0.05) -> None:
    """Poll ``predicate`` until it is true (for asserting on state that arrives over the bus)."""
    import asyncio

    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"condition not met within {timeout} s")
        await asyncio.sleep(interval)


@contextlib.asynccontextmanager
async def flooding(robot: Robot):  # type: ignore[no-untyped-def]
    """``odom/pose`` and ``hw/wheels`` published as fast as the loop can, far faster than any real
    stream, while the block runs: every reader thread of a program on the robot is busy."""
    import asyncio

    from icefloe.schemas import keys
    from icefloe.schemas import messages as m

    async with robot.node("streamer") as streamer:
        pose, wheels = streamer.publisher(keys.ODOM_POSE), streamer.publisher(keys.WHEELS)
        running = True

        async def stream() -> None:
            while running:
                for _ in range(50):
                    pose.put(m.Pose(stamp=1, x=0.0, y=0.0, theta=0.0))
                    wheels.put(m.Wheels(stamp=1, ticks_left=1, ticks_right=1, speed_left=0.0, speed_right=0.0))
                await asyncio.sleep(0)

        flood = asyncio.create_task(stream())
        try:
            yield
        finally:
            running = False
            await flood
