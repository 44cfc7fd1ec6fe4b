"""Never half-started: `icefloe up` checks the whole robot before it starts anything, and a service
that refuses its config stops the robot instead of being restarted forever (issue #15, item 7)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import ROOT, processes_naming, robot_config
from test_cli import wait_alive

from icefloe.errors import EXIT_CONFIG

ICEFLOE = [sys.executable, "-m", "icefloe.cli"]


def up_refuses(cfg: Path) -> str:
    """Run `icefloe up` on a robot it must refuse; the one line it printed."""
    res = subprocess.run([*ICEFLOE, "up", str(cfg), "--no-viz"], capture_output=True, text=True, timeout=60,
                         cwd=ROOT)
    assert res.returncode == EXIT_CONFIG, res.stdout + res.stderr
    assert res.stdout == "", "something was started"
    assert processes_naming(str(cfg)) == []
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("icefloe: "), res.stderr
    return lines[0]


def over(base: Path, toml: str) -> Path:
    """A config extending ``base`` (tables are merged, so this can add to its [zenoh] table)."""
    path = base.with_name(f"{base.stem}-bad.toml")
    path.write_text(f'extends = "{base}"\n{toml}\n')
    return path


def test_a_bad_value_starts_nothing(tmp_path: Path) -> None:
    cfg = robot_config(tmp_path, "deadman", "[hwbridge]\ndeadman_s = -1\n")
    assert up_refuses(cfg) == f"icefloe: {cfg}: hwbridge.deadman_s: Expected `float` > 0.0"


def test_access_control_without_credentials_starts_nothing(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere" / "robot.credentials"
    cfg = over(robot_config(tmp_path, "acl"), f'[zenoh]\naccess_control = true\ncredentials = "{missing}"\n')
    line = up_refuses(cfg)
    assert f"zenoh.access_control is on but there are no credentials at {missing}" in line
    # The router alone says the same in one line (it crash-looped with a traceback before).
    res = subprocess.run([*ICEFLOE, "router", str(cfg)], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert res.returncode == EXIT_CONFIG
    assert len(res.stderr.splitlines()) == 1 and "no credentials" in res.stderr and "Traceback" not in res.stderr


def test_a_real_board_whose_device_is_missing_starts_nothing(tmp_path: Path) -> None:
    port = tmp_path / "no-such-dir" / "ttyUSB7"
    cfg = robot_config(tmp_path, "hw", f'[board]\nbackend = "hardware"\nserial_port = "{port}"\n')
    line = up_refuses(cfg)
    assert line == (f'icefloe: {cfg}: board.serial_port: {port}: no such device '
                    f'(the penguinpi board, board.backend = "hardware")')
    assert not port.parent.exists()  # no simulator made it up


def test_a_real_board_never_gets_the_simulator(tmp_path: Path) -> None:
    cfg = robot_config(tmp_path, "hwsim", 'services = ["sim", "info"]\n'
                                          '[board]\nbackend = "hardware"\nserial_port = "/dev/null"\n')
    out = open(tmp_path / "up.log", "w+")  # noqa: SIM115
    up = subprocess.Popen([*ICEFLOE, "up", str(cfg), "--no-viz"], stdout=out, stderr=subprocess.STDOUT, cwd=ROOT,
                          start_new_session=True)
    try:
        wait_alive(cfg, "info", timeout=60)
        assert [p for p in processes_naming(str(cfg)) if p in processes_naming("icefloe.services.sim")] == []
        up.send_signal(signal.SIGINT)
        assert up.wait(30) == 0
        log = (tmp_path / "up.log").read_text()
        assert '[up    ] not starting sim: the board is real (board.backend = "hardware")' in log
        assert "[sim" not in log
    finally:
        if up.poll() is None:
            os.killpg(up.pid, signal.SIGKILL)
        out.close()


@pytest.mark.slow
def test_a_service_that_refuses_its_config_stops_the_robot(tmp_path: Path) -> None:
    cfg = robot_config(tmp_path, "edited", 'services = ["info", "odometry"]\n')
    out = open(tmp_path / "up.log", "w+")  # noqa: SIM115
    up = subprocess.Popen([*ICEFLOE, "up", str(cfg), "--no-viz"], stdout=out, stderr=subprocess.STDOUT, cwd=ROOT,
                          start_new_session=True)
    try:
        wait_alive(cfg, "odometry", timeout=60)
        # The config is edited while the robot runs, then odometry crashes: restarted, it reads
        # the bad value and refuses it; the robot stops instead of restarting it forever.
        cfg.write_text(cfg.read_text() + "\n[odometry]\nrate_hz = 0.0\n")
        odometry = [p for p in processes_naming(str(cfg)) if p in processes_naming("icefloe.services.odometry")]
        os.kill(odometry[0], signal.SIGKILL)
        assert up.wait(60) == EXIT_CONFIG
        time.sleep(0.2)
        assert processes_naming(str(cfg)) == []
        log = (tmp_path / "up.log").read_text()
        assert f"[odometry] icefloe: {cfg}: odometry.rate_hz: Expected `float` > 0.0" in log
        assert ("[up      ] odometry refused the robot's config (exit status 78; see above): not restarting it, "
                "stopping the robot") in log
        assert log.count("[odometry] exited with code") == 1  # the crash; no restart after the refusal
        assert "all stopped" in log
    finally:
        if up.poll() is None:
            os.killpg(up.pid, signal.SIGKILL)
        out.close()
