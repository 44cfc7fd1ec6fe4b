"""Errors a newcomer meets first: one line that says what to do, never a Rust path or a traceback."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import ROOT, free_port, robot_config

ICEFLOE = [sys.executable, "-m", "icefloe.cli"]


def one_line(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1, stderr
    assert ".rs:" not in stderr and ".cargo" not in stderr and "Traceback" not in stderr, stderr
    return lines[0]


def test_no_router(tmp_path: Path) -> None:
    cfg = robot_config(tmp_path, "norouter")  # nothing started: nobody listens on its port
    res = subprocess.run([*ICEFLOE, "echo", "odom/pose", "--config", str(cfg)], capture_output=True, text=True,
                         timeout=60)
    line = one_line(res.stderr)
    assert res.returncode == 2 and "nothing listens there" in line and "./deploy/up.sh" in line and "--connect" in line


def test_wrong_credentials(make_robot, tmp_path: Path) -> None:
    robot = make_robot(access_control=True)
    bad = tmp_path / "bad.credentials"
    bad.write_text(f'robot = "{robot.name}"\nuser = "{robot.name}"\npassword = "not the password"\n'
                   f'connect = ["tcp/127.0.0.1:{robot.port}"]\n')
    res = subprocess.run([*ICEFLOE, "status", "--credentials", str(bad)], capture_output=True, text=True, timeout=60)
    line = one_line(res.stderr)
    assert res.returncode == 2 and f"refused user '{robot.name}'" in line and "credentials" in line


def test_unknown_robot(tmp_path: Path) -> None:
    res = subprocess.run([*ICEFLOE, "status", "--config", "penguin99"], capture_output=True, text=True, timeout=60,
                         cwd=tmp_path)
    line = one_line(res.stderr)
    assert res.returncode == 2 and "penguin99: no robot config of that name (known:" in line and "sim" in line


@pytest.mark.slow
def test_a_service_that_cannot_start_says_why_once(tmp_path: Path) -> None:
    """`icefloe up penguin1` on a laptop: no credentials for its access control. One line, no restarts."""
    port = free_port()
    cfg = tmp_path / "locked.toml"
    cfg.write_text(f'extends = "sim"\nname = "locked{port}"\nrun_dir = "{tmp_path}/run"\nservices = ["info"]\n'
                   f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\nconnect = ["tcp/127.0.0.1:{port}"]\n'
                   f'access_control = true\ncredentials = "{tmp_path}/none.credentials"\n')
    alone = subprocess.run([sys.executable, "-m", "icefloe.router", "--config", str(cfg)], capture_output=True,
                           text=True, timeout=60)
    line = one_line(alone.stderr)
    assert alone.returncode == 2 and line.startswith("icefloe router: ") and "icefloe credentials" in line
    log = tmp_path / "up.log"
    with open(log, "w") as out:
        up = subprocess.Popen([*ICEFLOE, "up", str(cfg), "--no-viz"], stdout=out, stderr=subprocess.STDOUT, cwd=ROOT)
        deadline = time.monotonic() + 40
        while "not restarting it" not in log.read_text() and time.monotonic() < deadline:
            time.sleep(0.5)
        time.sleep(6.0)  # long enough for two restarts, were there any
        up.send_signal(2)
        up.wait(60)
    router = [line for line in log.read_text().splitlines() if line.startswith("[router")]
    assert any("icefloe credentials" in line for line in router), router
    assert any("not restarting it" in line for line in router), router
    assert not any("restarting in" in line for line in router) and "Traceback" not in log.read_text(), router


def test_robot_without_a_stack_is_not_reachable_at_once(tmp_path: Path) -> None:
    """`Robot("sim")` with nothing running: a clean NotReachable within about a second."""
    robots = tmp_path / "robots"
    robots.mkdir()
    port = free_port()
    (robots / "sim.toml").write_text(f'extends = "sim"\n[zenoh]\nconnect = ["tcp/127.0.0.1:{port}"]\n')
    script = ("import time, traceback\nfrom icefloe import Robot\nfrom icefloe.errors import NotReachable\n"
              "t = time.monotonic()\ntry:\n    Robot('sim')\nexcept NotReachable:\n"
              "    print(round(time.monotonic() - t, 2))\n    print(traceback.format_exc())\n")
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60,
                         env={**os.environ, "ICEFLOE_CONFIG_DIR": str(tmp_path)})
    elapsed, trace = res.stdout.split("\n", 1)
    assert float(elapsed) < 5.0, res.stdout  # 1 s of retries for a router that is starting, on a busy machine
    assert f"NotReachable: robot 'sim': no Zenoh router answers at tcp/127.0.0.1:{port}" in trace
    assert "nothing listens there" in trace and "./deploy/up.sh" in trace
    assert "concurrent" not in trace and "During handling" not in trace and trace.count("File ") <= 3, trace
