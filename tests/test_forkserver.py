"""The fork server (icefloe/forkserver.py): services started as copies of one process that imported
everything once.

1. Which cgroup files a process's cgroups are, from real-looking /proc texts (v2, v1, hybrid).
2. A real server, a real requester and a real service (`info`): the service is made like the
   requester (user, groups, limits, nice value, CPUs, working folder, umask, environment), is
   adopted by the requester's subreaper, shows its own command line, and its exit status reaches
   its adopter; a module that is not icefloe's, and a user the server does not serve, are refused
   in one line, and `start` then runs the service on its own. As root (CI is): the user changes.
3. `icefloe up` with it is tests/test_stack.py's and test_cli.py's; under systemd, the box's
   (tests/test_box.py: every unit's main process is the service, in the unit's cgroup).
"""

from __future__ import annotations

import ctypes
import json
import os
import pwd
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from conftest import free_port

from icefloe import forkserver
from icefloe.deploy import SERVICE_ENV

V2 = "29 1 0:26 / /sys/fs/cgroup rw,nosuid,nodev,noexec,relatime shared:4 - cgroup2 cgroup2 rw,nsdelegate\n"
V1 = (
    "30 25 0:27 / /sys/fs/cgroup/systemd rw,nosuid,nodev,noexec,relatime shared:5 - cgroup cgroup "
    "rw,xattr,name=systemd\n"
    "33 25 0:30 / /sys/fs/cgroup/cpu,cpuacct rw,nosuid,nodev,noexec,relatime shared:14 - cgroup cgroup "
    "rw,cpu,cpuacct\n"
    "34 25 0:31 / /sys/fs/cgroup/memory rw,nosuid,nodev,noexec,relatime shared:15 - cgroup cgroup rw,memory\n"
    "35 25 0:32 / /sys/fs/cgroup/unified rw,nosuid,nodev,noexec,relatime shared:6 - cgroup2 cgroup2 rw\n"
    "22 1 8:1 / / rw,relatime shared:1 - ext4 /dev/vda rw\n"
)


def test_cgroup_v2_has_one_file() -> None:
    procs = forkserver.cgroup_procs("0::/system.slice/icefloe@odometry.service\n", forkserver.cgroup_mounts(V2))
    assert procs == [Path("/sys/fs/cgroup/system.slice/icefloe@odometry.service/cgroup.procs")]


def test_cgroup_v1_has_one_file_a_hierarchy_whatever_the_order_of_its_controllers() -> None:
    cgroup = ("12:memory:/system.slice/icefloe-hwbridge.service\n"
              "4:cpuacct,cpu:/system.slice\n"
              "1:name=systemd:/system.slice/icefloe-hwbridge.service\n"
              "0::/system.slice/icefloe-hwbridge.service\n")
    assert forkserver.cgroup_procs(cgroup, forkserver.cgroup_mounts(V1)) == [
        Path("/sys/fs/cgroup/memory/system.slice/icefloe-hwbridge.service/cgroup.procs"),
        Path("/sys/fs/cgroup/cpu,cpuacct/system.slice/cgroup.procs"),
        Path("/sys/fs/cgroup/systemd/system.slice/icefloe-hwbridge.service/cgroup.procs"),
        Path("/sys/fs/cgroup/unified/system.slice/icefloe-hwbridge.service/cgroup.procs"),
    ]


NSPAWN_ON_V1 = (  # the robot in a box (systemd-nspawn) on a cgroup v1 host: the host's controllers read-only
    "59 115 0:52 / /sys/fs/cgroup ro,nosuid,nodev,noexec shared:15 - tmpfs tmpfs ro,size=4096k\n"
    "62 59 0:36 / /sys/fs/cgroup/pids ro,nosuid,nodev,noexec,relatime shared:18 - cgroup cgroup rw,pids\n"
    "63 59 0:29 / /sys/fs/cgroup/cpu ro,nosuid,nodev,noexec,relatime shared:19 - cgroup cgroup rw,cpu\n"
    "68 59 0:38 /payload /sys/fs/cgroup/unified rw,nosuid,nodev,noexec,relatime shared:24 - cgroup2 cgroup rw\n"
    "69 59 0:37 /payload /sys/fs/cgroup/systemd rw,nosuid,nodev,noexec,relatime shared:25 - cgroup cgroup "
    "rw,name=systemd\n"
)


def test_only_the_hierarchies_that_differ_are_joined_so_a_containers_read_only_ones_are_left_alone() -> None:
    """Found in the box: the server wrote the requester's "/" into the host's read-only pids hierarchy,
    was refused with EROFS, and every unit started without it."""
    def cgroup(unit: str) -> str:
        return f"9:name=systemd:/system.slice/{unit}\n8:pids:/\n1:cpu:/\n0::/system.slice/{unit}\n"

    server, unit = cgroup("icefloe-forkserver.service"), cgroup("icefloe-router.service")
    assert forkserver.cgroups_to_join(unit, server, forkserver.cgroup_mounts(NSPAWN_ON_V1)) == [
        Path("/sys/fs/cgroup/systemd/system.slice/icefloe-router.service/cgroup.procs"),
        Path("/sys/fs/cgroup/unified/system.slice/icefloe-router.service/cgroup.procs"),
    ]
    assert forkserver.cgroups_to_join(server, server, forkserver.cgroup_mounts(NSPAWN_ON_V1)) == []


def test_a_request_that_is_not_json_is_refused() -> None:
    with pytest.raises(forkserver.Refused, match="not a request"):
        forkserver.Request.decode(b"\xff")


# ---------------------------------------------------------------------------- real processes


def subreaper() -> None:
    """This test process adopts the services the server forks (as `icefloe up` does)."""
    ctypes.CDLL(None, use_errno=True).prctl(forkserver.PR_SET_CHILD_SUBREAPER, 1)


@pytest.fixture
def open_dir():  # type: ignore[no-untyped-def]
    """A folder any user may enter (pytest's own are in a 0700 folder): for ``nobody``'s files."""
    folder = Path(tempfile.mkdtemp(prefix="icefloe-forkserver-"))
    folder.chmod(0o755)
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture
def server(open_dir: Path, tmp_path: Path):  # type: ignore[no-untyped-def]
    """A fork server serving root and ``nobody``, its socket in a folder ``nobody`` may enter."""
    sock = open_dir / "forkserver.sock"
    log = open(tmp_path / "server.log", "w+")  # noqa: SIM115
    users = ["--user", "nobody"] if os.geteuid() == 0 else []
    proc = subprocess.Popen([sys.executable, "-m", "icefloe.forkserver", "serve", "--socket", str(sock), *users],
                            stderr=log, env={**os.environ, **SERVICE_ENV})
    deadline = time.monotonic() + 60
    while "ready" not in Path(log.name).read_text():
        assert proc.poll() is None and time.monotonic() < deadline, Path(log.name).read_text()
        time.sleep(0.1)
    subreaper()
    yield sock, Path(log.name)
    proc.send_signal(signal.SIGINT)
    proc.wait(30)
    log.close()
    assert not sock.exists(), "the server leaves no socket behind"


def robot(tmp_path: Path, owner: int = 0) -> Path:
    """A config for `info` (a router on a free port that nobody runs: info keeps trying)."""
    run = tmp_path / "robot-run"
    run.mkdir(mode=0o700)
    os.chown(run, owner, -1)
    cfg = tmp_path / "fs.toml"
    port = free_port()
    cfg.write_text(f'extends = "sim"\nname = "fs{port}"\nrun_dir = "{run}"\n[zenoh]\n'
                   f'listen = []\nconnect = ["tcp/127.0.0.1:{port}"]\n')
    os.chmod(cfg, 0o644)
    return cfg


def status(pid: int) -> dict[str, str]:
    return dict(line.split(":\t", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines()
                if ":\t" in line)


def wait_gone(pid: int, timeout: float = 30.0) -> int:
    """The exit status of an adopted service, once it has ended."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        done, code = os.waitpid(pid, os.WNOHANG)
        if done:
            return os.waitstatus_to_exitcode(code)
        time.sleep(0.05)
    raise AssertionError(f"pid {pid} still running after {timeout} s")


REQUESTER = """
import json, os, resource, sys
from icefloe import forkserver
os.nice(5)
resource.setrlimit(resource.RLIMIT_NOFILE, (321, 321))
os.sched_setaffinity(0, {0})
os.umask(0o027)
os.chdir(sys.argv[2])
if (uid := int(sys.argv[3])) >= 0:   # (a user of its own only now: it may not be able to run python)
    gid = int(sys.argv[4])
    os.setgroups([]); os.setgid(gid); os.setuid(uid)
req = forkserver.Request(sys.argv[5], sys.argv[6:], {"PATH": os.environ["PATH"]})
try:
    print(json.dumps({"pid": forkserver.request(sys.argv[1], req, (0, 2, 2))}), flush=True)
except forkserver.Refused as exc:
    print(json.dumps({"refused": str(exc)}), flush=True)
"""


def ask(sock: Path, cwd: Path, module: str, *args: str, user: str = "") -> dict:
    """A requester process (as ``user``, with its own nice value, limits, CPUs, umask and folder)."""
    uid, gid = (pwd.getpwnam(user).pw_uid, pwd.getpwnam(user).pw_gid) if user else (-1, -1)
    with open(cwd / "service.log", "a") as log:   # the service's output, and the requester's
        res = subprocess.run([sys.executable, "-c", REQUESTER, str(sock), str(cwd), str(uid), str(gid), module,
                              *args], stdout=subprocess.PIPE, stderr=log, text=True, timeout=60, cwd=cwd)
    assert res.stdout, (cwd / "service.log").read_text()
    return json.loads(res.stdout.splitlines()[0])


def readable_by_all(path: Path) -> bool:
    """Can any user read this checkout (every folder above it searchable)? Not in a 0700 home."""
    return all(os.stat(p).st_mode & 0o005 == 0o005 for p in [path, *path.parents])


def other_user_can_run_python() -> str:
    """Why ``nobody`` cannot run this Python and checkout (a forked service still imports modules
    as it runs), or "" when it can. Here Python may live in a 0700 home (pyenv in /root); a robot's
    is /usr's, and the box checks the user change there (tests/test_box.py)."""
    for path in (Path(sys.base_prefix), Path(forkserver.__file__).parent):
        closed = [p for p in [path, *path.parents] if os.stat(p).st_mode & 0o005 != 0o005]
        if closed:
            return f"{closed[0]} is closed to other users ({path} is in it)"
    return ""


@pytest.mark.parametrize("user", ["root", "nobody"])
@pytest.mark.skipif(os.geteuid() != 0, reason="needs root: the server changes users (CI runs as root)")
def test_a_service_is_made_like_its_requester_and_adopted(server, open_dir: Path, user: str) -> None:  # type: ignore[no-untyped-def]
    if user != "root" and (why := other_user_can_run_python()):
        pytest.skip(why)
    sock, _log = server
    entry = pwd.getpwnam(user)
    cwd = open_dir / "cwd"
    cwd.mkdir(mode=0o755)
    cfg = robot(open_dir, owner=entry.pw_uid)
    answer = ask(sock, cwd, "icefloe.services.info", "--config", str(cfg), user=user if user != "root" else "")
    pid = answer["pid"]
    try:
        s = status(pid)
        assert s["State"][0] in "RS", (s["State"], _log.read_text())
        assert s["Uid"].split()[0] == str(entry.pw_uid) and s["Gid"].split()[0] == str(entry.pw_gid)
        assert s["Umask"] == "0027"
        assert s["Cpus_allowed_list"] == "0"
        assert os.getpriority(os.PRIO_PROCESS, pid) == 5
        assert os.readlink(f"/proc/{pid}/cwd") == str(cwd)
        import resource

        assert resource.prlimit(pid, resource.RLIMIT_NOFILE) == (321, 321)
        assert int(s["PPid"]) == os.getpid()   # adopted by this process, the subreaper
        title = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode().strip()
        assert title == f"{sys.executable} -m icefloe.services.info --config {cfg}"
        # SIGINT once the service runs its loop (before, it is Python's KeyboardInterrupt: a loaded machine)
        deadline = time.monotonic() + 60
        while "retrying" not in (cwd / "service.log").read_text() and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        os.kill(pid, signal.SIGINT)
    assert wait_gone(pid) == 0


def test_the_service_gets_the_requesters_environment_and_its_exit_status_reaches_the_adopter(
        server, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """``ICEFLOE_CONFIG_DIR`` from the request decides where the robot name is looked up: the service's
    line names the folder, and its exit status (78: the config) reaches this process."""
    sock, _log = server
    mine = tmp_path / "mine"
    (mine / "robots").mkdir(parents=True)
    (mine / "robots" / "broken.toml").write_text("nonsense_key = 1\n")
    out = tmp_path / "service.log"
    with open(out, "w") as stream:
        req = forkserver.Request("icefloe.services.info", ["--config", "broken"],
                                 {"ICEFLOE_CONFIG_DIR": str(mine), "PATH": os.environ["PATH"]})
        pid = forkserver.request(sock, req, (0, stream.fileno(), stream.fileno()))
    assert wait_gone(pid) == 78
    text = out.read_text()
    assert str(mine / "robots" / "broken.toml") in text and "nonsense_key" in text, text


def test_a_module_that_is_not_icefloes_is_refused_in_one_line(server, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    sock, log = server
    for module in ("os", "http.server", "icefloe.cli", "icefloe.services.info.__main__ ; rm", "icefloe.services"):
        with pytest.raises(forkserver.Refused, match="is not an icefloe service"):
            forkserver.request(sock, forkserver.Request(module, [], {}), (0, 1, 2))
    assert log.read_text().count("is not an icefloe service") == 5


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root: a second user to ask")
def test_a_user_the_server_does_not_serve_is_refused(open_dir: Path) -> None:
    """A server that serves root only; ``nobody`` asks: refused, in one line."""
    sock = open_dir / "fs.sock"
    server = subprocess.Popen([sys.executable, "-m", "icefloe.forkserver", "serve", "--socket", str(sock)],
                              stderr=subprocess.PIPE, text=True, env={**os.environ, **SERVICE_ENV})
    try:
        while not sock.exists():
            assert server.poll() is None
            time.sleep(0.1)
        os.chmod(sock, 0o666)   # so that the refusal is the server's, not the socket's mode
        answer = ask(sock, open_dir, "icefloe.services.info", "--help", user="nobody")
        assert answer["refused"].startswith(f"user {pwd.getpwnam('nobody').pw_uid} may not ask this server")
    finally:
        server.send_signal(signal.SIGINT)
        _, err = server.communicate(timeout=30)
    assert len([line for line in err.splitlines() if "may not ask" in line]) == 1, err


def test_start_runs_the_service_on_its_own_when_the_server_does_not_answer(tmp_path: Path) -> None:
    """A unit's ExecStart with no fork server running: one line saying so, systemd is told the unit is
    ready (Type=notify: else the unit stays "activating", as it did in the box), and the service runs."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as systemd:
        systemd.bind(str(tmp_path / "notify"))
        res = subprocess.run([sys.executable, "-m", "icefloe.forkserver", "start", "--socket", str(tmp_path / "none"),
                              "icefloe.services.info", "--help"], capture_output=True, text=True, timeout=60,
                             env={**os.environ, "NOTIFY_SOCKET": str(tmp_path / "notify")})
        systemd.settimeout(5)
        told = systemd.recv(4096)
    assert res.returncode == 0 and "usage:" in res.stdout, res.stderr
    assert len(res.stderr.splitlines()) == 1 and "did not start it" in res.stderr, res.stderr
    assert told == b"READY=1"


def test_start_without_systemd_runs_the_service_as_python_m_would(tmp_path: Path) -> None:
    res = subprocess.run([sys.executable, "-m", "icefloe.forkserver", "start", "--socket", str(tmp_path / "none"),
                          "icefloe.services.info", "--help"], capture_output=True, text=True, timeout=60,
                         env={k: v for k, v in os.environ.items() if k != "NOTIFY_SOCKET"})
    assert res.returncode == 0 and "usage:" in res.stdout and res.stderr == "", res.stderr
