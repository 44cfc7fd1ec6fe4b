"""`icefloe up`: run every service of a robot as its own process.

Before anything starts, the whole robot is checked (`problems`): the config's values
(checked when it was read), credentials when access control is on, the devices of a
real board, the files the services read. A robot that cannot run starts nothing and
says why, one line per problem. A real board (``board.backend = "hardware"``) never
gets the simulator.

The fork server starts first (`icefloe.forkserver`: it imports what every service imports,
once, and the router and services start as copies of it, sharing those pages), then the
router (every service is a client of it), then the services
listed in the robot config, in order, and your own programs (``[programs.<name>]``,
`program_environment` says what they are told). Each child's output is prefixed with its
name. A child that dies is restarted with back-off (1 s, 2 s, 4 s ... 30 s; the
back-off resets once it has run for a minute), except:

* one that exits with `EXIT_CONFIG` (78: it refused the config; starting it again cannot help):
  then the whole robot stops, saying so;
* one that exits 0 (it is done, e.g. the viewer was closed) or `CANNOT_START` (2: it cannot
  start here, a missing device or a port in use, and said why): it is not restarted;
* a program with ``restart = false``.

Ctrl-C (or SIGTERM) stops the services in reverse order with SIGTERM (a service exits
cleanly, as on Ctrl-C; one still starting up just ends, without a traceback from the middle
of an import), waits, and kills what is left, so no process stays behind. A program gets its
signals in its whole process group, as a terminal delivers Ctrl-C: a shell script stops with
the commands it is running.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import multiprocessing
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from . import config as config_mod
from . import forkserver
from .config import RobotConfig
from .deploy import SERVICE_ENV
from .errors import EXIT_CONFIG, ConfigError
from .runtime import CANNOT_START, run_async

DONE = {0: "finished", CANNOT_START: "it cannot start as configured (see above)"}
"""Exit statuses after which a child is not restarted (like systemd's Restart=on-failure with
RestartPreventExitStatus=2). `EXIT_CONFIG` stops the whole robot."""
STOP_TIMEOUT = 8.0
MAX_BACKOFF = 30.0
HEALTHY_AFTER = 60.0


def _die_with_parent(sig: int = signal.SIGINT) -> Callable[[], None]:
    """In the child, before exec: on Linux, get ``sig`` when the launcher dies, however it dies,
    so a killed `icefloe up` leaves no service behind (and hwbridge still stops the wheels).
    Programs get SIGTERM: a shell script puts off SIGINT until the command it runs ends."""
    def arm() -> None:
        if sys.platform == "linux":
            import ctypes

            pr_set_pdeathsig = 1
            ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, sig)

    return arm


def available(service: str) -> bool:
    """Is there a ``services/<service>`` package to run?"""
    try:
        return importlib.util.find_spec(f"icefloe.services.{service}.__main__") is not None
    except ModuleNotFoundError:
        return False


def webapi_url(config: RobotConfig) -> str:
    """Where this machine reaches the robot's web API (and its HTTP bridge to the bus)."""
    host = config.webapi.host
    if host in ("", "0.0.0.0", "::"):
        host = "127.0.0.1"
    return f"http://{f'[{host}]' if ':' in host else host}:{config.webapi.port}"


def program_environment(config: RobotConfig, config_path: Path, name: str) -> dict[str, str]:
    """The environment variables a program of yours gets from `icefloe up` (docs/own-services.md):

    ``ICEFLOE_ROBOT``        the robot's name: its keys are ``icefloe/<robot>/...``
    ``ICEFLOE_SERVICE``      the program's name (``[programs.<name>]``): its liveliness token is
                             ``icefloe/<robot>/alive/<name>``
    ``ICEFLOE_CONNECT``      the robot's Zenoh router, e.g. ``tcp/127.0.0.1:7447`` (comma-separated
                             if several)
    ``ICEFLOE_CREDENTIALS``  the robot's credentials file (user and password; set when the config
                             names one): a path, so the password is never in an environment
                             listing or on a command line
    ``ICEFLOE_CONFIG``       the robot config file (icefloe's Python `run` reads it by default)
    ``ICEFLOE_WEBAPI``       the web API and its HTTP bridge to the bus, e.g. ``http://127.0.0.1:8080``
    """
    env = {
        "ICEFLOE_ROBOT": config.name,
        "ICEFLOE_SERVICE": name,
        "ICEFLOE_CONNECT": ",".join(config.zenoh.connect),
        "ICEFLOE_CONFIG": str(config_path.resolve()),
        "ICEFLOE_WEBAPI": webapi_url(config),
    }
    if config.zenoh.credentials and (creds := Path(config.zenoh.credentials).expanduser()).is_file():
        env["ICEFLOE_CREDENTIALS"] = str(creds.resolve())
    return env


class Adopted:
    """A service the fork server started, which the launcher adopted (it is a child subreaper):
    waited for through a pidfd, as `asyncio.subprocess.Process` is through its own watcher."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.returncode: int | None = None
        self._exited = asyncio.get_running_loop().create_future()
        self._pidfd = os.pidfd_open(pid)
        asyncio.get_running_loop().add_reader(self._pidfd, self._reap)

    def _reap(self) -> None:
        with contextlib.suppress(ChildProcessError):
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid == 0:
                return  # not yet: the pidfd says so before the kernel lets us reap it
            self.returncode = os.waitstatus_to_exitcode(status)
        asyncio.get_running_loop().remove_reader(self._pidfd)
        os.close(self._pidfd)
        if not self._exited.done():
            self._exited.set_result(self.returncode)

    async def wait(self) -> int:
        await asyncio.shield(self._exited)
        return self.returncode if self.returncode is not None else -1

    def send_signal(self, sig: int) -> None:
        os.kill(self.pid, sig)


@dataclass
class Child:
    name: str
    argv: list[str]
    env: dict[str, str] = field(default_factory=dict)
    """Besides the launcher's own environment."""
    cwd: str | None = None
    program: bool = False
    """One of yours (``[programs.<name>]``): signalled as a process group."""
    restart: bool = True
    module: str = ""
    """An icefloe module (the router, a service): the fork server can start it."""
    process: asyncio.subprocess.Process | Adopted | None = None
    started: float = 0.0
    restarts: int = 0
    backoff: float = 1.0
    pumps: list[asyncio.Task[None]] = field(default_factory=list)


class Launcher:
    def __init__(self, config: RobotConfig, config_path: Path, services: list[str],
                 *, out: object = None, fork_server: bool = True) -> None:
        """``services``: icefloe's own services and names of ``[programs.<name>]``, in order.
        ``fork_server``: start icefloe's own as copies of a fork server (Linux only)."""
        self.config = config
        self.out = out or sys.stdout
        width = max([len(s) for s in services] + [6])
        self._fmt = f"[{{:<{width}}}] "
        base = [sys.executable, "-m"]
        cfg = ["--config", str(config_path)]
        self.socket: Path | None = None
        """The fork server's socket, once it listens."""
        self.children = []
        if fork_server and sys.platform == "linux":
            sock = config_mod.private_dir(config.runtime_dir) / "forkserver.sock"
            self.children.append(Child("forkserver", [*base, "icefloe.forkserver", "serve", "--socket", str(sock)]))
        self.children.append(Child("router", [*base, "icefloe.router", *cfg], module="icefloe.router"))
        for name in services:
            if (program := config.programs.get(name)) is not None:
                env = {**program_environment(config, config_path, name), **program.env}
                self.children.append(Child(name, list(program.command), env, program.cwd or None,
                                           program=True, restart=program.restart))
            else:
                module = f"icefloe.services.{name}"
                self.children.append(Child(name, [*base, module, *cfg], module=module))
        self._stopping = False
        self._stop = asyncio.Event()
        self.refused: str | None = None
        """The service that exited with `EXIT_CONFIG`, if one did (the robot then stopped)."""

    def say(self, name: str, line: str) -> None:
        print(self._fmt.format(name) + line, file=self.out, flush=True)

    async def _pump(self, child: Child, stream: asyncio.StreamReader) -> None:
        while line := await stream.readline():
            self.say(child.name, line.decode(errors="replace").rstrip())

    async def _start(self, child: Child) -> bool:
        """Start the child's process; False (said why) if it cannot be started at all."""
        own = {"PYTHONUNBUFFERED": "1"} if child.program else SERVICE_ENV  # yours: as you set it up
        env = {**os.environ, **own, **child.env}
        if child.module and self.socket is not None and await self._fork(child, env):
            return True
        try:
            child.process = await asyncio.create_subprocess_exec(
                *child.argv, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
                env=env, cwd=child.cwd, start_new_session=True,  # our own Ctrl-C handling decides the order
                preexec_fn=_die_with_parent(signal.SIGTERM if child.program else signal.SIGINT),
            )
        except OSError as exc:  # no such program, not executable, no such folder
            where = f" in {child.cwd}" if child.cwd else ""
            self.say(child.name, f"cannot start {child.argv[0]}{where}: {exc.strerror}")
            return False
        child.started = time.monotonic()
        assert child.process.stdout is not None
        child.pumps = [asyncio.create_task(self._pump(child, child.process.stdout))]
        return True

    async def _fork(self, child: Child, env: dict[str, str]) -> bool:
        """Start an icefloe module as a copy of the fork server, its output to us; False (said once)
        if the server does not: the caller then starts it on its own."""
        read, write = os.pipe()
        try:
            with open(os.devnull, "rb") as null:
                req = forkserver.Request(child.module, child.argv[3:], env, adopter=os.getpid(),
                                         adopter_death_signal=signal.SIGINT)
                pid = await asyncio.to_thread(forkserver.request, self.socket, req, (null.fileno(), write, write))
        except (OSError, forkserver.Refused) as exc:
            os.close(read)
            self.say("up", f"the fork server did not start {child.name} ({exc}): starting it on its own")
            return False
        finally:
            os.close(write)
        child.process = Adopted(pid)
        child.started = time.monotonic()
        reader = asyncio.StreamReader()
        loop = asyncio.get_running_loop()
        await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), os.fdopen(read, "rb"))
        child.pumps = [asyncio.create_task(self._pump(child, reader))]
        return True

    async def _wait_fork_server(self, server: Child) -> None:
        """Until the fork server listens (its socket answers), or has died: then services start on their own."""
        sock = Path(server.argv[-1])
        for _ in range(600):   # 30 s: importing NumPy and OpenCV on a Pi 3B takes seconds
            if server.process is not None and server.process.returncode is not None:
                return
            if sock.exists():
                self.socket = sock
                return
            await asyncio.sleep(0.05)

    async def _supervise(self, child: Child) -> None:
        while not self._stopping:
            if not await self._start(child):
                return  # it will not start by trying again: the rest of the robot runs on
            assert child.process is not None
            code = await child.process.wait()
            if child.program:  # what it started and left behind (a killed script's curl) goes too
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(child.process.pid, signal.SIGKILL)
            await asyncio.gather(*child.pumps, return_exceptions=True)
            if self._stopping:
                return
            if code == EXIT_CONFIG:
                self.say("up", f"{child.name} refused the robot's config (exit status {code}; see above): "
                               "not restarting it, stopping the robot")
                self.refused = child.name
                self._stop.set()
                return
            if code in DONE:  # it chose to end (the viewer was closed), or says restarting cannot help
                self.say(child.name, f"exited with code {code}: {DONE[code]}; not restarting it")
                return
            if not child.restart:
                self.say(child.name, f"exited with code {code}; not restarting it (restart = false)")
                return
            if time.monotonic() - child.started > HEALTHY_AFTER:
                child.backoff = 1.0
            self.say(child.name, f"exited with code {code}; restarting in {child.backoff:.0f} s")
            child.restarts += 1
            await asyncio.sleep(child.backoff)
            child.backoff = min(child.backoff * 2, MAX_BACKOFF)

    async def _wait_router(self) -> None:
        """Give the router a moment to listen so the services' first connect succeeds (or to fail)."""
        host_port = self.config.zenoh.connect[0].split("/", 1)[-1] if self.config.zenoh.connect else ""
        host, _, port = host_port.rpartition(":")
        for _ in range(100):
            if self._stop.is_set():
                return
            with contextlib.suppress(OSError):
                _, writer = await asyncio.open_connection(host or "127.0.0.1", int(port))
                writer.close()
                return
            await asyncio.sleep(0.05)

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        stop = self._stop
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        tasks = []
        if self.children[0].name == "forkserver":
            with contextlib.suppress(OSError):   # it adopts the services the fork server starts
                import ctypes

                ctypes.CDLL(None, use_errno=True).prctl(forkserver.PR_SET_CHILD_SUBREAPER, 1)
            tasks.append(asyncio.create_task(self._supervise(self.children[0])))
            await self._wait_fork_server(self.children[0])
        router, *services = [c for c in self.children if c.name != "forkserver"]
        tasks.append(asyncio.create_task(self._supervise(router)))
        await self._wait_router()
        if not stop.is_set():  # (the router may have refused the config already)
            tasks += [asyncio.create_task(self._supervise(c)) for c in services]
            self.say("up", f"robot {self.config.name!r}: {', '.join(c.name for c in [router, *services])} "
                     f"(Ctrl-C stops them all)")
        await stop.wait()
        await self.stop()
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    async def stop(self) -> None:
        """SIGTERM to the services in reverse order (router last), then SIGKILL what remains."""
        self._stopping = True
        self.say("up", "stopping")
        for child in reversed(self.children):
            if child.process and child.process.returncode is None:
                with contextlib.suppress(ProcessLookupError):
                    if child.program:  # the script and the commands it runs
                        os.killpg(child.process.pid, signal.SIGTERM)
                    else:
                        child.process.send_signal(signal.SIGTERM)
                try:
                    await asyncio.wait_for(child.process.wait(), STOP_TIMEOUT)
                except TimeoutError:
                    self.say(child.name, f"did not stop within {STOP_TIMEOUT} s; killing it")
                    with contextlib.suppress(ProcessLookupError):
                        os.killpg(child.process.pid, signal.SIGKILL)
                    await child.process.wait()
        self.say("up", "all stopped")


def up(config: RobotConfig, config_path: Path, wanted: list[str], fork_server: bool = True) -> int:
    """Check the robot, then run the router and the ``wanted`` services and programs that exist,
    until Ctrl-C.
    Returns the exit status: 0, or `EXIT_CONFIG` when the robot cannot run with this config."""
    services = [s for s in wanted if s in config.programs or available(s)]
    notes = []
    if missing := [s for s in wanted if s not in services]:
        notes.append(f"not available yet, skipped: {', '.join(missing)}")
    if config.board.backend == "hardware" and "sim" in services:
        services.remove("sim")
        notes.append('not starting sim: the board is real (board.backend = "hardware")')
    found = problems_in_a_child(config, services)
    for problem in found:
        print(f"icefloe: {problem}", file=sys.stderr, flush=True)
    if found:
        return EXIT_CONFIG
    launcher = Launcher(config, config_path, services, fork_server=fork_server)
    for note in notes:
        launcher.say("up", note)
    run_async(launcher.run())
    return EXIT_CONFIG if launcher.refused else 0


# ---------------------------------------------------------------------- before anything starts


def problems_in_a_child(config: RobotConfig, services: Sequence[str]) -> list[str]:
    """`problems`, found by a forked process on Linux (the robot): what the checks import (OpenCV
    for the camera's calibration, 30 MB) does not stay in the launcher, which runs as long as the
    robot. (Forking is safe here: the launcher has no threads yet.)"""
    if sys.platform != "linux":
        return problems(config, services)
    with multiprocessing.get_context("fork").Pool(1) as pool:
        return pool.apply(problems, (config, list(services)))


def problems(config: RobotConfig, services: Sequence[str]) -> list[str]:
    """Why this robot cannot run ``services``, one line each (none: it can).

    The values of the config were checked when it was read (`icefloe.config`); here is what
    depends on the machine and on the files the services read: credentials, a real board's
    devices, world maps, the camera's calibration, the simulator's device paths.
    """
    from .config import private_dir
    from .router import check_router
    from .worldmap import load_world

    found: list[str] = []

    def check(what: Callable[[], object]) -> None:
        try:
            what()
        except ConfigError as exc:
            found.append(str(exc))

    check(lambda: private_dir(config.runtime_dir))  # (each service makes it so too: here it is said once)
    b = config.board
    if "hwbridge" in services and b.backend == "hardware":
        key, path = ("serial_port", b.serial_port) if b.kind == "penguinpi" else ("spi_device", b.spi_device)
        check(lambda: _device(config, f"board.{key}", path, f'the {b.kind} board, board.backend = "hardware"'))
    if "power" in services and config.power.gpio == "gpiod":
        check(lambda: _device(config, "power.gpio_chip", config.power.gpio_chip, 'power.gpio = "gpiod"'))
    if "oled" in services and config.display.kind == "ssd1306":
        check(lambda: _device(config, "display.i2c_port", f"/dev/i2c-{config.display.i2c_port}",
                              'display.kind = "ssd1306"'))
    if "sim" in services:
        from .services.sim.simulator import check_config as check_sim

        check(lambda: check_sim(config))
        check(lambda: load_world(config.sim.world))
    if "localizer" in services:
        check(lambda: load_world(config.localizer.world))
    if "camera" in services:
        from .services.camera.detection import make_detector  # dictionary, calibration file

        check(lambda: make_detector(config))
    z = config.zenoh
    for key in ("config", "tls_certificate", "tls_private_key", "tls_root_ca"):
        path = getattr(z, key)
        if path and not Path(path).expanduser().is_file():
            found.append(f"{config.source}: zenoh.{key}: {path}: no such file")
    if not found:  # (with its files there) credentials, the guest, the lab link
        check(lambda: check_router(config))
    return found


def _device(config: RobotConfig, key: str, path: str, why: str) -> None:
    p = Path(path)
    if not p.exists():
        raise ConfigError(f"{config.source}: {key}: {path}: no such device ({why})")
    if not (p.is_char_device() or p.is_block_device()):
        raise ConfigError(f"{config.source}: {key}: {path} is not a device ({why})")
