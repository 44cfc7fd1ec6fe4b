"""The `icefloe` command and `icefloe up`, as real processes over a real router."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import ROOT, Robot, processes_naming, robot_config
from terminal import Terminal

from icefloe.errors import EXIT_CONFIG

ICEFLOE = [sys.executable, "-m", "icefloe.cli"]


def icefloe(robot: Robot, *args: str, timeout: float = 20.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*ICEFLOE, *args, "--config", str(robot.config_path)], capture_output=True,
                          text=True, timeout=timeout, cwd=ROOT)


def wait_alive(robot: Robot | Path, service: str, timeout: float = 15.0) -> str:
    """Wait until `icefloe status` lists ``service`` on the robot (a test robot or a config file)."""
    config = robot if isinstance(robot, Path) else robot.config_path
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        out = subprocess.run([*ICEFLOE, "status", "--config", str(config)], capture_output=True, text=True,
                             timeout=20, cwd=ROOT).stdout
        if service in out.split():
            return out
        time.sleep(0.2)
    raise AssertionError(f"{service} not alive on {config}: {out!r}")


def test_two_processes_exchange_a_message(robot: Robot) -> None:
    echo = subprocess.Popen([*ICEFLOE, "echo", "cmd/twist", "--count", "1", "--config", str(robot.config_path)],
                            stdout=subprocess.PIPE, text=True, cwd=ROOT)
    time.sleep(1.5)
    pub = icefloe(robot, "pub", "cmd/twist", '{"v": 0.1, "w": -0.2}', "--rate", "5", "--count", "10")
    assert pub.returncode == 0, pub.stderr
    out, _ = echo.communicate(timeout=10)
    assert json.loads(out.splitlines()[0]) == {"v": 0.1, "w": -0.2}


def test_pub_checks_the_schema_before_sending(robot: Robot) -> None:
    bad = icefloe(robot, "pub", "cmd/twist", '{"v": "fast", "w": 0}')
    assert bad.returncode == 2
    assert "cmd/twist: Expected `float`, got `str` - at `$.v`" in bad.stderr


def test_status_query_and_echo_log_against_a_service(robot: Robot) -> None:
    log = subprocess.Popen([*ICEFLOE, "echo", "log", "--duration", "20", "--config", str(robot.config_path)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    # it listens, and says why nothing comes yet: nobody publishes on log (and, when the robot's services
    # of earlier tests are gone, that none of this robot is alive: a line before)
    warnings = [log.stderr.readline()]
    if "no publisher is declared" not in warnings[0]:
        warnings.append(log.stderr.readline())
    assert "no publisher is declared" in warnings[-1], warnings
    info = robot.start("info")
    assert "info" in wait_alive(robot, "info")
    answer = icefloe(robot, "query", "info")
    assert json.loads(answer.stdout)["name"] == robot.name
    info.stop()
    log.send_signal(signal.SIGINT)
    out, _ = log.communicate(timeout=10)
    lines = [json.loads(line) for line in out.splitlines()]
    assert any(e["service"] == "info" and "serving" in e["text"] for e in lines), out


def test_echo_at_a_terminal_says_it_listens(robot: Robot) -> None:
    """A student's `icefloe echo log` on a robot at rest would print nothing for minutes: at a terminal
    it says what it listens on (stderr), and Ctrl-C ends it cleanly."""
    term = Terminal([*ICEFLOE, "echo", "log", "--config", str(robot.config_path)], cwd=ROOT)
    try:
        deadline = time.monotonic() + 30
        while f"listening on icefloe/{robot.name}/log (Ctrl-C stops)" not in term.text:
            assert term.alive() and time.monotonic() < deadline, term.text
            time.sleep(0.1)
        term.ctrl_c()
        assert term.wait(20) in (0, 130, -2), term.text
        assert "Traceback" not in term.text, term.text
    finally:
        term.kill()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_service_exits_cleanly_on_signal(robot: Robot, sig: int) -> None:
    info = robot.start("info")
    wait_alive(robot, "info")
    t0 = time.monotonic()
    assert info.stop(sig, timeout=5.0) == 0
    assert time.monotonic() - t0 < 5.0


def test_status_fails_fast_without_a_router(tmp_path: Path) -> None:
    cfg = tmp_path / "r.toml"
    cfg.write_text(f'extends = "{ROOT}/deploy/robots/sim.toml"\n[zenoh]\nconnect = ["tcp/127.0.0.1:9"]\n')
    res = subprocess.run([*ICEFLOE, "status", "--config", str(cfg)], capture_output=True, text=True, timeout=20)
    assert res.returncode == 2
    assert "cannot reach a Zenoh router at tcp/127.0.0.1:9" in res.stderr


def test_up_rejects_a_bad_config_and_starts_nothing(tmp_path: Path) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text('[hwbridge]\ndeadman_s = "soon"\n')
    res = subprocess.run([*ICEFLOE, "up", str(cfg), "--no-viz"], capture_output=True, text=True, timeout=20)
    assert res.returncode == EXIT_CONFIG
    assert "bad.toml: hwbridge.deadman_s: Expected `float`, got `str`" in res.stderr


def test_up_runs_restarts_and_stops_everything(tmp_path: Path) -> None:
    cfg = robot_config(tmp_path, "uptest", 'services = ["info", "nosuch"]')
    out = open(tmp_path / "up.log", "w+")  # noqa: SIM115
    up = subprocess.Popen([*ICEFLOE, "up", str(cfg), "--no-viz"], stdout=out, stderr=subprocess.STDOUT,
                          cwd=ROOT, start_new_session=True)
    try:
        wait_alive(cfg, "info")
        wait_alive(cfg, "router")
        info_pid = next(p for p in processes_naming(str(cfg)) if p in processes_naming("icefloe.services.info"))
        os.kill(info_pid, signal.SIGKILL)  # a crash
        time.sleep(0.5)
        wait_alive(cfg, "info")
        up.send_signal(signal.SIGINT)
        assert up.wait(20) == 0
        time.sleep(0.2)
        assert processes_naming(str(cfg)) == []
        log = (tmp_path / "up.log").read_text()
        assert "not available yet, skipped: nosuch" in log
        assert "[info  ] exited with code -9; restarting in 1 s" in log
        assert "[router] router for" in log
        assert "all stopped" in log
    finally:
        if up.poll() is None:
            os.killpg(up.pid, signal.SIGKILL)
        out.close()


def test_services_stop_when_up_is_killed(tmp_path: Path) -> None:
    cfg = robot_config(tmp_path, "killed", 'services = ["info"]')
    up = subprocess.Popen([*ICEFLOE, "up", str(cfg), "--no-viz"], stdout=subprocess.DEVNULL,
                          stderr=subprocess.DEVNULL, cwd=ROOT)
    wait_alive(cfg, "info")
    up.kill()  # SIGKILL: no chance to clean up
    up.wait()
    deadline = time.monotonic() + 10
    while processes_naming(str(cfg)) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert processes_naming(str(cfg)) == []


def test_schemas_check_passes_on_the_checked_in_files() -> None:
    res = subprocess.run([*ICEFLOE, "schemas", "--check"], capture_output=True, text=True, timeout=30)
    assert res.returncode == 0, res.stdout
