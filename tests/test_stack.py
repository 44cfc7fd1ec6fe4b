"""The whole simulated robot, as `./deploy/up.sh` runs it: every service a process, one Ctrl-C stops all."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import time
from pathlib import Path

from conftest import ROOT, free_port, processes_naming, robot_config, stop_up

from icefloe import config as config_mod
from icefloe.deploy import SERVICE_ENV
from icefloe.launcher import available

sys.path.insert(0, str(ROOT / "bench"))
from stack_cpu import children  # service name -> pids, as the CPU bench finds them

ICEFLOE = [sys.executable, "-m", "icefloe.cli"]


def _environ(pid: int) -> dict[str, str]:
    pairs = Path(f"/proc/{pid}/environ").read_bytes().decode(errors="replace").split("\0")
    return dict(pair.split("=", 1) for pair in pairs if "=" in pair)


def _parent(pid: int) -> int:
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])


def test_the_default_stack_runs_reports_and_stops_cleanly(tmp_path: Path) -> None:
    cfg = robot_config(tmp_path, "stack", f"[webapi]\nport = {free_port()}\n")
    expected = [s for s in config_mod.load(cfg).services if available(s)]
    log = open(tmp_path / "up.log", "w+")  # noqa: SIM115
    echo = open(tmp_path / "echo.log", "w+")  # noqa: SIM115
    up = subprocess.Popen([*ICEFLOE, "up", str(cfg), "--no-viz"], stdout=log, stderr=subprocess.STDOUT, cwd=ROOT,
                          start_new_session=True)
    tail = None
    try:
        deadline = time.monotonic() + 60
        alive: list[str] = []
        while time.monotonic() < deadline and not set(expected) <= set(alive):
            time.sleep(1.0)
            res = subprocess.run([*ICEFLOE, "status", "--config", str(cfg)], capture_output=True, text=True,
                                 timeout=30)
            alive = res.stdout.split(":", 1)[-1].split()
        assert set(expected) <= set(alive), f"alive {alive}, expected {expected}\n{Path(log.name).read_text()}"
        assert "router" in alive
        # Each service runs with the environment its systemd unit gives it on a robot. The fork server
        # started all but hwbridge's cycle, as copies of itself: glibc's and Python's settings
        # (SERVICE_ENV) took effect in it when it started, and it holds no thread that a fork would copy
        # (OPENBLAS_NUM_THREADS). What a forked service sees in os.environ is tests/test_forkserver.py's:
        # /proc/<pid>/environ shows the server's memory, which setproctitle took for the titles.
        services = {name: pids for name, pids in children(cfg).items() if name != "launcher"}
        assert set(expected) | {"router"} <= set(services), services
        server = processes_naming(f"icefloe.forkserver serve --socket {config_mod.load(cfg).runtime_dir}")
        assert len(server) == 1 and "Threads:\t1\n" in Path(f"/proc/{server[0]}/status").read_text(), server
        for name, pids in services.items():
            for pid in pids:
                if name == "hwbridge (cycle)":   # hwbridge starts it as a fresh Python (it locks its memory)
                    assert SERVICE_ENV.items() <= _environ(pid).items(), (name, _environ(pid))
                else:                            # the launcher adopted what the fork server started
                    assert _parent(pid) == up.pid, (name, pid, _parent(pid))
        tail = subprocess.Popen([*ICEFLOE, "echo", "log", "-n", "1", "--duration", "60", "--config", str(cfg)],
                                stdout=echo, cwd=ROOT)
        # Something worth a log line: a bad command, which hwbridge must reject and survive. Sent
        # again until the echo (which may take a while to subscribe on a busy machine) has shown one.
        while tail.poll() is None:
            subprocess.run([*ICEFLOE, "pub", "cmd/twist", '{"v": 99.0, "w": 0}', "--config", str(cfg)], timeout=30)
            with contextlib.suppress(subprocess.TimeoutExpired):
                tail.wait(timeout=3)
        lines = [json.loads(line) for line in Path(echo.name).read_text().splitlines() if line.strip()]
        assert lines, "no log lines on the bus"
        assert all({"stamp", "level", "service", "text"} <= set(e) for e in lines)
    finally:
        try:
            code = stop_up(up)
        finally:
            log.close()
            echo.close()
    assert code == 0
    time.sleep(0.5)
    left = processes_naming(str(cfg))
    assert left == [], f"processes left behind: {left}\n{Path(log.name).read_text()}"
    assert "all stopped" in Path(log.name).read_text()
