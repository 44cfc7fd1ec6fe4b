"""The fork server: icefloe's services start as copies of one process that has already imported what
they all import, so that those pages are shared between them, not held once per service.

A Python service holds about 14 MiB of its own before it does anything: the interpreter, asyncio,
Zenoh, msgspec, NumPy, icefloe's runtime, each imported into private memory. Nine such processes
on a Raspberry Pi 3B (1 GB, shared with the students' programs) are most of the robot's memory. A
process made by ``fork()`` shares its parent's pages until it writes to them, so the server
imports everything once (`PRELOAD`), freezes it (``gc.freeze``: the collector then never writes to
those objects) and forks each service on request. Every service stays its own process, in its
own systemd unit, started, stopped, restarted and logged as before; a student's replacement
is started as it always was. docs/deploy.md, "Memory", has the figures.

    python -m icefloe.forkserver serve --socket PATH [--user NAME]   the server
    python -m icefloe.forkserver start --socket PATH MODULE [ARG...]  a systemd unit's ExecStart

How a service starts (``start``, run by systemd as the unit's user, with the unit's limits,
scheduling, CPUs and environment):

1. it sends the server a `Request` (the module to run as ``python -m`` would, its arguments and
   environment) and its standard input, output and error (the unit's journal stream);
2. the server forks a child, which forks the service and exits at once: the service, an orphan,
   becomes the child of PID 1 (systemd), which therefore reaps it and sees its exit status;
3. the server moves the service into the requester's cgroups (its unit's), then lets it go on;
4. the service makes itself like the requester: the same user, groups, resource limits,
   scheduling policy and priority, CPUs, nice value, OOM score, working folder and umask
   (read from ``/proc/<requester>`` by the server before it answers, so that the unit file stays
   the one place they are set), then runs the module;
5. ``start`` tells systemd the service's pid (``MAINPID=``, with ``READY=1``) and exits.

Under ``icefloe up`` the launcher is the requester and adopts the services itself (it is a
child subreaper). The server never starts a service it would not be sure of: a request for a
module that is not icefloe's, from a user other than the one it serves, or while the server has
a second thread (a fork would copy a lock another thread holds) is refused in one line, and
``start`` then runs the service on its own, as ``python -m`` would: the robot runs, with more memory.

What the services share with the server also goes on after a fork: the hash seed of ``str`` (the
same in every service), and the imported modules' state. So the server imports modules only,
opens no session and starts no thread; ``random`` reseeds itself in every child.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import importlib
import json
import os
import pwd
import re
import resource
import runpy
import signal
import socket
import struct
import sys
from dataclasses import dataclass, field
from pathlib import Path

import setproctitle

PRELOAD = (
    # what every service imports (the runtime and what it stands on)
    "asyncio", "uvloop", "zenoh", "msgspec", "icefloe.runtime", "icefloe.config", "icefloe.schemas.codec",
    # what most of the robot's services import: numpy (odometry's models, the localizer, the
    # camera, the OLED's frames), OpenCV (camera, localizer), aiohttp (the web API)
    "numpy", "cv2", "aiohttp.web",
)
"""Imported by the server before it forks anything (a module that is not installed is skipped)."""
MODULE = re.compile(r"icefloe\.(services\.[a-z][a-z0-9_]*|router|sim\.[a-z][a-z0-9_]*)")
"""What the server starts: icefloe's own services and router, nothing else."""
REPLY_TIMEOUT_S = 10.0
"""``start`` gives up on the server after this long, and starts the service on its own."""
LIMITS = [getattr(resource, n) for n in dir(resource) if n.startswith("RLIMIT_")]
PR_SET_PDEATHSIG, PR_SET_CHILD_SUBREAPER = 1, 36


class Refused(Exception):
    """The server will not start this (the message says why)."""


@dataclass
class Request:
    module: str
    """Run as ``python -m MODULE`` would run it."""
    argv: list[str]
    env: dict[str, str]
    adopter: int = 1
    """Whose child the service becomes: PID 1 (systemd), or a launcher that is a child subreaper."""
    adopter_death_signal: int = 0
    """Sent to the service when its adopter dies (``icefloe up``: a killed launcher leaves nothing)."""

    def encode(self) -> bytes:
        return json.dumps(self.__dict__).encode()

    @classmethod
    def decode(cls, data: bytes) -> Request:
        try:
            return cls(**json.loads(data))
        except (ValueError, TypeError) as exc:
            raise Refused(f"not a request ({exc})") from None


# ---------------------------------------------------------------------------- the server


@dataclass
class Server:
    path: Path
    users: set[int]
    """Who may ask: root, the server's own user, the ``--user`` it serves."""
    started: int = 0
    preloaded: list[str] = field(default_factory=list)

    def preload(self) -> None:
        # setproctitle takes over the memory of argv (and of the environment behind it) the first time
        # it sets a title; done here, with the environment whole, every forked service can set its own.
        setproctitle.setproctitle(setproctitle.getproctitle())
        for name in PRELOAD:
            with contextlib.suppress(ImportError):
                importlib.import_module(name)
                self.preloaded.append(name)
        gc.collect()
        gc.freeze()

    def serve(self) -> None:
        """Accept requests until SIGTERM or SIGINT; in a forked service, raise `Become` instead."""
        server = os.getpid()
        self.path.unlink(missing_ok=True)
        with contextlib.ExitStack() as cleanup, socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as listener:
            cleanup.callback(lambda: os.getpid() == server and self.path.unlink(missing_ok=True))
            listener.bind(str(self.path))
            os.chmod(self.path, 0o660)
            served = [u for u in self.users if u != 0 and u != os.getuid()]
            if served and os.getuid() == 0:
                os.chown(self.path, 0, pwd.getpwuid(served[0]).pw_gid)
            listener.listen(16)
            say(f"ready: {len(self.preloaded)} modules imported once for every service "
                f"({', '.join(self.preloaded)}); listening on {self.path}")
            notify_systemd("READY=1")
            while True:
                conn, _ = listener.accept()
                with conn:
                    self.answer(conn)

    def answer(self, conn: socket.socket) -> None:
        pid, uid, _ = struct.unpack("3i", conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, 12))
        fds: list[int] = []
        try:
            conn.settimeout(REPLY_TIMEOUT_S)
            data, fds, _, _ = socket.recv_fds(conn, 1 << 16, 3)
            request = Request.decode(data)
            if uid not in self.users:
                raise Refused(f"user {uid} may not ask this server (it serves {sorted(self.users)})")
            if not MODULE.fullmatch(request.module):
                raise Refused(f"{request.module!r} is not an icefloe service")
            if len(fds) != 3:
                raise Refused(f"a request brings standard input, output and error ({len(fds)} given)")
            if (threads := len(os.listdir("/proc/self/task"))) != 1:
                raise Refused(f"the server has {threads} threads: a fork would copy their locks held")
            try:  # now, while the requester waits for the answer: it may end as soon as it has one
                like = Likeness.of(pid)
            except (OSError, KeyError, ValueError) as exc:
                raise Refused(f"cannot read what pid {pid} is like: {exc}") from None
            service = self.fork(request, pid, like, fds)
            conn.sendall(json.dumps({"pid": service}).encode())
            self.started += 1
            say(f"started {request.module} as pid {service} for pid {pid}")
        except Refused as exc:
            say(f"refused pid {pid}: {exc}")
            with contextlib.suppress(OSError):
                conn.sendall(json.dumps({"refused": str(exc)}).encode())
        except OSError as exc:
            say(f"pid {pid}: {exc}")
        finally:
            for fd in fds:
                os.close(fd)

    def fork(self, request: Request, requester: int, like: Likeness, fds: list[int]) -> int:
        """Fork the service (see the module's docstring); its pid. In the service, raise `Become`."""
        go_r, go_w = os.pipe()
        pid_r, pid_w = os.pipe()
        middle = os.fork()
        if middle == 0:  # the child: fork the service, say its pid, and leave it an orphan
            try:
                service = os.fork()
                if service:
                    os.write(pid_w, str(service).encode())
            except BaseException:
                os._exit(1)
            if service:
                os._exit(0)
            try:  # the service: never back into the server's loop, whatever happens here
                streams = [os.dup(fd) for fd in fds]   # the server's frames close the originals
                for fd in (go_w, pid_r, pid_w):
                    os.close(fd)
                go = os.read(go_r, 2) == b"go"   # the server has moved us into the requester's cgroups
                os.close(go_r)
            except BaseException:
                os._exit(1)
            raise Become(request, like, streams, go)
        os.close(pid_w)
        os.close(go_r)
        service = int(os.read(pid_r, 32) or b"0")
        os.close(pid_r)
        os.waitpid(middle, 0)
        try:
            if service <= 0:
                raise Refused("the service's process did not start")
            join_cgroups(service, like=requester)
            os.write(go_w, b"go")
        except (OSError, Refused) as exc:
            os.write(go_w, b"no")   # it ends without running anything
            raise Refused(f"cannot put the service into the cgroups of pid {requester}: {exc}") from None
        finally:
            os.close(go_w)
        return service


class Become(BaseException):  # not an error: a forked service unwinding the server's stack
    """Raised in a forked service: the server's frames unwind (closing its socket), and `main`
    then turns this process into the service (`become`)."""

    def __init__(self, request: Request, like: Likeness, fds: list[int], go: bool) -> None:
        self.request, self.like, self.fds, self.go = request, like, fds, go


@dataclass(frozen=True)
class Likeness:
    """What a service copies from its requester, read by the server before it answers (after the
    answer a unit's requester ends, and its ``/proc`` entry with it)."""

    pid: int
    limits: dict[int, tuple[int, int]]
    cpus: set[int]
    nice: int
    policy: int
    priority: int
    oom_score_adj: str
    umask: int
    cwd: str
    uid: int
    gid: int
    groups: list[int]

    @classmethod
    def of(cls, pid: int) -> Likeness:
        limits = {}
        for n in LIMITS:
            with contextlib.suppress(OSError, ValueError):
                limits[n] = resource.prlimit(pid, n)
        status = dict(line.split(":\t", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines()
                      if ":\t" in line)
        return cls(pid=pid, limits=limits, cpus=os.sched_getaffinity(pid),
                   nice=os.getpriority(os.PRIO_PROCESS, pid), policy=os.sched_getscheduler(pid),
                   priority=os.sched_getparam(pid).sched_priority,
                   oom_score_adj=Path(f"/proc/{pid}/oom_score_adj").read_text(),
                   umask=int(status.get("Umask", "0022"), 8), cwd=os.readlink(f"/proc/{pid}/cwd"),
                   uid=int(status["Uid"].split()[0]), gid=int(status["Gid"].split()[0]),
                   groups=[int(g) for g in status.get("Groups", "").split()])


# ---------------------------------------------------------------------------- cgroups


def cgroup_mounts(mountinfo: str) -> list[tuple[frozenset[str], str]]:
    """The cgroup hierarchies mounted here, from ``/proc/self/mountinfo``: (what each holds, its
    mount point). What a hierarchy holds is empty for cgroup v2; for v1, its superblock options,
    among them its controllers (``cpu``, ``cpuacct``) or its name (``name=systemd``)."""
    out = []
    for line in mountinfo.splitlines():
        left, _, right = line.partition(" - ")
        fstype, _source, options = [*right.split(), "", "", ""][:3]
        if fstype == "cgroup2":
            out.append((frozenset(), left.split()[4]))
        elif fstype == "cgroup":
            out.append((frozenset(options.split(",")), left.split()[4]))
    return out


def cgroup_procs(cgroup: str, mounts: list[tuple[frozenset[str], str]]) -> list[Path]:
    """The ``cgroup.procs`` files of a process's cgroups (``cgroup``: the text of ``/proc/<pid>/cgroup``,
    one ``hierarchy:controllers:path`` line per hierarchy)."""
    out = []
    for line in cgroup.splitlines():
        hierarchy, controllers, path = line.split(":", 2)
        wanted = frozenset(controllers.split(",")) if controllers else frozenset()
        for holds, point in mounts:
            if (hierarchy == "0" and not holds) or (wanted and wanted <= holds):
                out.append(Path(point + path.rstrip("/")) / "cgroup.procs")
                break
    return out


def join_cgroups(pid: int, like: int) -> None:
    """Move ``pid`` into the cgroups of ``like`` (nothing to do when they are already the same)."""
    theirs, ours = Path(f"/proc/{like}/cgroup").read_text(), Path(f"/proc/{pid}/cgroup").read_text()
    for procs in cgroups_to_join(theirs, ours, cgroup_mounts(Path("/proc/self/mountinfo").read_text())):
        procs.write_text(str(pid))


def cgroups_to_join(theirs: str, ours: str, mounts: list[tuple[frozenset[str], str]]) -> list[Path]:
    """The ``cgroup.procs`` files to write to go from cgroups ``ours`` to ``theirs`` (texts of
    ``/proc/<pid>/cgroup``): only the hierarchies where the two differ. The others may be mounted
    read-only (systemd-nspawn on a cgroup v1 host: the controllers are the host's, every process is in
    "/" of them, and only the box's own hierarchies are its systemd's)."""
    differ = "\n".join(line for line in theirs.splitlines() if line not in set(ours.splitlines()))
    return cgroup_procs(differ, mounts)


# ---------------------------------------------------------------------------- the service


def become(b: Become) -> None:
    """Make this forked process like the requester (see the module's docstring), then run the
    module as ``python -m`` would; its exit is this process's exit."""
    if not b.go:
        os._exit(1)
    r, like = b.request, b.like
    try:
        for n, limit in like.limits.items():
            with contextlib.suppress(OSError, ValueError):
                resource.setrlimit(n, limit)
        with contextlib.suppress(OSError):
            os.sched_setaffinity(0, like.cpus)
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, 0, like.nice)
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, like.policy, os.sched_param(like.priority))
        with contextlib.suppress(OSError):
            Path("/proc/self/oom_score_adj").write_text(like.oom_score_adj)
        os.umask(like.umask)
        if os.getuid() == 0 and like.uid != 0:
            os.setgroups(like.groups)
            os.setgid(like.gid)
            os.setuid(like.uid)  # the last step: from here on, no privilege is left
        elif os.getuid() != like.uid:
            raise PermissionError(f"the server runs as {os.getuid()}, the requester as {like.uid}")
        os.chdir(like.cwd)
    except OSError as exc:
        say(f"pid {os.getpid()}: cannot become like pid {like.pid}: {exc}")
        os._exit(1)
    os.setsid()
    for target, fd in enumerate(b.fds):
        os.dup2(fd, target)
        os.close(fd)
    for number in (signal.SIGTERM, signal.SIGCHLD, signal.SIGHUP):
        signal.signal(number, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.pthread_sigmask(signal.SIG_SETMASK, [])
    if r.adopter_death_signal:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, r.adopter_death_signal)
        if os.getppid() != r.adopter:  # it died before we could ask to follow it
            os._exit(1)
    os.environ.clear()
    os.environ.update(r.env)
    os.environ.pop("NOTIFY_SOCKET", None)  # the requester's conversation with systemd, not ours
    # (what was frozen stays frozen: collecting it would write to every page of it, unsharing them)
    sys.argv = [r.module, *r.argv]
    # what `ps`, `top` and `pgrep -f` show: the command line it would have had on its own
    setproctitle.setproctitle(" ".join([sys.executable, "-m", r.module, *r.argv]))
    runpy.run_module(r.module, run_name="__main__", alter_sys=True)


# ---------------------------------------------------------------------------- asking


def request(path: str | os.PathLike[str], req: Request, fds: tuple[int, int, int] = (0, 1, 2),
            timeout: float = REPLY_TIMEOUT_S) -> int:
    """Ask the server at ``path`` to start ``req`` with these standard streams; the service's pid.
    `Refused` (or `OSError`) when it does not."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as conn:
        conn.settimeout(timeout)
        conn.connect(os.fspath(path))
        socket.send_fds(conn, [req.encode()], list(fds))
        answer = json.loads(conn.recv(1 << 16) or b"{}")
    if "pid" not in answer:
        raise Refused(answer.get("refused", "no answer"))
    return int(answer["pid"])


def notify_systemd(state: str, barrier: bool = False) -> bool:
    """Tell systemd ``state`` (``READY=1``, ``MAINPID=...``) if it is listening ($NOTIFY_SOCKET);
    ``barrier``: return only once systemd has read it (a requester about to exit)."""
    where = os.environ.get("NOTIFY_SOCKET")
    if not where:
        return False
    address = "\0" + where[1:] if where.startswith("@") else where
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.connect(address)
        sock.sendall(state.encode())
        if barrier:  # sd_notify_barrier: systemd closes our pipe once it has handled what came before
            r, w = os.pipe()
            socket.send_fds(sock, [b"BARRIER=1"], [w])
            os.close(w)
            import select

            select.select([r], [], [], 5.0)
            os.close(r)
    return True


def start(path: str, module: str, argv: list[str]) -> None:
    """A unit's ExecStart: the service from the server, its pid told to systemd; on its own, as
    ``python -m`` would run it, if the server does not start it."""
    if os.environ.get("NOTIFY_SOCKET"):
        try:
            pid = request(path, Request(module, argv, dict(os.environ)))
        except (OSError, Refused, ValueError) as exc:
            say(f"{module}: the fork server at {path} did not start it ({exc}): starting it on its own "
                "(it then holds its own copy of every module)")
            notify_systemd("READY=1")  # Type=notify: this pid, after the exec below, is the service
        else:
            notify_systemd(f"MAINPID={pid}\nREADY=1", barrier=True)
            return
    os.execv(sys.executable, [sys.executable, "-m", module, *argv])


def say(line: str) -> None:
    print(f"forkserver: {line}", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m icefloe.forkserver", description=__doc__.split("\n\n")[0])
    verbs = p.add_subparsers(dest="verb", required=True)
    serve = verbs.add_parser("serve", help="import once, then fork each service asked for")
    serve.add_argument("--socket", required=True, help="the Unix socket to listen on")
    serve.add_argument("--user", default="", help="the user whose services it starts (besides root and its own)")
    go = verbs.add_parser("start", help="start a service through the server (a systemd unit's ExecStart)")
    go.add_argument("--socket", required=True, help="the server's Unix socket")
    go.add_argument("module", help="the module to run, as python -m would (icefloe.services.NAME)")
    go.add_argument("args", nargs=argparse.REMAINDER, help="its arguments")
    args = p.parse_args(argv)
    if args.verb == "start":
        start(args.socket, args.module, args.args)
        return
    users = {0, os.getuid()} | ({pwd.getpwnam(args.user).pw_uid} if args.user else set())
    server = Server(Path(args.socket), users)
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    server.preload()
    try:
        server.serve()
    except Become as b:   # this process is a forked service now: the server's frames are gone
        become(b)
    except KeyboardInterrupt:
        say(f"stopped after starting {server.started} services")


if __name__ == "__main__":
    main()
