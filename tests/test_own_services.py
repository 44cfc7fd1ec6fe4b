"""Your own services under `icefloe up` (``[programs.<name>]``, docs/own-services.md): a Python
service made by `icefloe new-service`, a shell script that uses curl on the HTTP bridge, and a
raw-Zenoh program (as a C or Rust service would be). They run with the robot, are restarted when
killed, and stop with it; the ones on Zenoh appear in `icefloe status` and `icefloe services`."""

from __future__ import annotations

import asyncio
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import ROOT, free_port, processes_naming, robot_config, stop_up
from test_cli import wait_alive

from icefloe import config as config_mod
from icefloe.runtime import Node
from icefloe.schemas import keys

ICEFLOE = [sys.executable, "-m", "icefloe.cli"]


def icefloe(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*ICEFLOE, *args], capture_output=True, text=True, timeout=60, cwd=cwd)


def test_new_service_writes_a_service_that_passes_its_own_test(tmp_path: Path) -> None:
    made = icefloe("new-service", "odo_check", "--dir", str(tmp_path))
    assert made.returncode == 0, made.stderr
    folder = tmp_path / "odo_check"
    assert sorted(p.name for p in folder.iterdir()) == ["README.md", "odo_check.py", "robot.toml",
                                                        "test_odo_check.py"]
    assert "example_service" not in "".join(p.read_text() for p in folder.iterdir())
    tested = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_odo_check.py"],
                            capture_output=True, text=True, timeout=120, cwd=folder)
    assert tested.returncode == 0, tested.stdout + tested.stderr
    assert "2 passed" in tested.stdout
    assert config_mod.load(folder / "robot.toml").programs["odo_check"].cwd == str(folder)
    lint = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--isolated", "--select",
                           "E,F,W,I,B,UP,SIM", "."], capture_output=True, text=True, timeout=60, cwd=folder)
    assert lint.returncode == 0, lint.stdout
    again = icefloe("new-service", "odo_check", "--dir", str(tmp_path))
    assert again.returncode == 2 and "exists already" in again.stderr
    for bad in ("Odo", "2fast", "hwbridge", "my-service"):
        refused = icefloe("new-service", bad, "--dir", str(tmp_path))
        assert refused.returncode == 2 and bad in refused.stderr, refused.stderr


def pids(text: str) -> set[int]:
    return set(processes_naming(text))


def parent(pid: int) -> int:
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return 0


def program_pids(text: str) -> set[int]:
    """The programs themselves: a shell script's own subshells (``$(...)``, ``<(...)``) carry its
    command line too, but live for milliseconds and have the script as their parent."""
    found = pids(text)
    return {pid for pid in found if parent(pid) not in found}


def until(predicate, what: str, timeout: float = 60.0):  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while not (value := predicate()):
        assert time.monotonic() < deadline, f"not within {timeout} s: {what}"
        time.sleep(0.2)
    return value


async def screen_texts(config, count: int, timeout: float = 60.0) -> list[str]:
    """The next ``count`` oled/text messages (the shell service writes the battery there)."""
    async with Node("tester", config, announce=False) as node:
        texts = node.subscribe(keys.OLED_TEXT)
        return [(await asyncio.wait_for(anext(texts), timeout)).text for _ in range(count)]


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_up_runs_supervises_and_stops_your_own_programs(tmp_path: Path) -> None:
    assert icefloe("new-service", "odo_check", "--dir", str(tmp_path)).returncode == 0
    shutil.copy(ROOT / "examples" / "curl_service.sh", tmp_path / "curl_service.sh")
    cfg = robot_config(tmp_path, "own", (
        'services = ["sim", "hwbridge", "odometry", "info", "webapi"]\n'
        f'[webapi]\nhost = "127.0.0.1"\nport = {free_port()}\n'
        '[programs.odo_check]\ncommand = ["{python}", "odo_check/odo_check.py"]\n'  # relative: to the config's folder
        '[programs.battery_screen]\ncommand = ["bash", "./curl_service.sh"]\n'
        f'[programs.forward]\ncommand = ["{{python}}", "{ROOT}/examples/raw_zenoh_service.py"]\n'))
    config = config_mod.load(cfg)
    log = open(tmp_path / "up.log", "w+")  # noqa: SIM115
    up = subprocess.Popen([*ICEFLOE, "up", str(cfg), "--no-viz"], stdout=log, stderr=subprocess.STDOUT, cwd=ROOT,
                          start_new_session=True)
    # What names each program's processes in `ps` (unique to this test: other tests run elsewhere).
    bridge = f"127.0.0.1:{config.webapi.port}/bus"
    scripts = {"odo_check": "odo_check/odo_check.py", "battery_screen": "./curl_service.sh",
               "forward": f"{ROOT}/examples/raw_zenoh_service.py"}
    try:
        for name in ("odo_check", "forward"):  # on Zenoh: their own liveliness tokens
            wait_alive(cfg, name, timeout=90)
        texts = asyncio.run(screen_texts(config, 2))  # the shell script's PUTs on the HTTP bridge
        assert all(t.startswith("battery ") and t.endswith(" V") for t in texts), texts
        services = icefloe("services", "--config", str(cfg))
        assert f"{config.name}/forward" in services.stdout, services.stdout
        # Each program was told its robot, router, credentials and bridge, not the password.
        first = {name: until(lambda s=script: program_pids(s), f"{name} running") for name, script in scripts.items()}
        environ = Path(f"/proc/{min(first['battery_screen'])}/environ").read_bytes().split(b"\0")
        assert f"ICEFLOE_ROBOT={config.name}".encode() in environ
        assert f"ICEFLOE_WEBAPI=http://127.0.0.1:{config.webapi.port}".encode() in environ
        assert f"ICEFLOE_CONNECT={config.zenoh.connect[0]}".encode() in environ
        # A crash: SIGKILL each. `icefloe up` starts them again.
        for name in scripts:
            for pid in first[name]:
                os.kill(pid, signal.SIGKILL)
        for name, script in scripts.items():
            until(lambda s=script, n=name: program_pids(s) - first[n], f"{name} restarted")
        for name in ("odo_check", "forward"):
            wait_alive(cfg, name, timeout=60)
        assert asyncio.run(screen_texts(config, 1))[0].startswith("battery ")
    finally:
        try:
            code = stop_up(up)
        finally:
            log.close()
    output = (tmp_path / "up.log").read_text()
    assert code == 0, output
    for name in scripts:
        assert f"[{name:<14}] exited with code -9; restarting in 1 s" in output, output
    time.sleep(0.5)
    left = [p for text in (str(cfg), *scripts.values(), bridge) for p in pids(text)]
    assert left == [], f"left behind: {left}\n{output}"
    assert "all stopped" in output
