"""deploy/up.sh on a robot, as far as a machine without a Pi allows: the dry run and the units."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT

from icefloe import config, deploy


@pytest.fixture(scope="module")
def dry_run() -> str:
    res = subprocess.run(["./deploy/up.sh", "penguin1", "--dry-run"], capture_output=True, text=True,
                         cwd=ROOT, timeout=300)
    assert res.returncode == 0, res.stderr
    return res.stdout


def test_dry_run_lists_every_unit_and_changes_nothing(dry_run: str) -> None:
    assert "icefloe install for robot 'penguin1'" in dry_run
    assert "(dry run: nothing changed)" in dry_run
    for unit in ("icefloe.target", "icefloe-router.service", "icefloe-hwbridge.service", "icefloe@.service"):
        assert f"write /etc/systemd/system/{unit}" in dry_run
        assert not (Path("/etc/systemd/system") / unit).exists()
    enable = next(line for line in dry_run.splitlines() if line.startswith("  run: systemctl enable icefloe.target"))
    for service in ("odometry", "camera", "power", "oled", "webapi", "localizer"):
        assert f"icefloe@{service}.service" in enable
    assert "icefloe@sim.service" not in enable  # a real robot runs no simulator


def test_dry_run_shows_the_real_time_settings_of_hwbridge(dry_run: str) -> None:
    unit = dry_run.split("write /etc/systemd/system/icefloe-hwbridge.service")[1].split("\n* ")[0]
    for setting in ("CPUSchedulingPolicy=fifo", "CPUSchedulingPriority=", "LimitMEMLOCK=infinity",
                    "LimitRTPRIO=", "CPUAffinity=", "KillSignal=SIGINT", "Restart=on-failure",
                    "RestartPreventExitStatus=2 78"):
        assert setting in unit, setting
    assert "isolcpus=" in dry_run


def test_every_unit_gives_its_process_the_service_environment() -> None:
    cfg = config.load("penguin1")
    rendered = deploy.units(cfg, deploy.ROBOTS / "penguin1.toml", "/opt/icefloe/venv/bin/python")
    want = "Environment=" + " ".join(f"{k}={v}" for k, v in deploy.SERVICE_ENV.items())
    for name, text in rendered.items():
        assert "{" not in text, (name, text)  # every placeholder filled in
        if name.endswith(".service"):
            assert want in text.splitlines(), (name, text)


def test_dry_run_shows_the_permission_steps(dry_run: str) -> None:
    assert "usermod -aG dialout,spi,i2c,gpio,video icefloe" in dry_run
    assert "write /etc/udev/rules.d/99-icefloe.rules" in dry_run
    assert 'SUBSYSTEM=="spidev", GROUP="spi"' in dry_run
    assert "enable_uart=1" in dry_run and "dtparam=spi=on" in dry_run and "dtparam=i2c_arm=on" in dry_run
    assert "console=serial0" in dry_run
    assert "icefloe credentials: /etc/icefloe/penguin1.credentials" in dry_run and "owner icefloe, mode 0600" in dry_run


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed")
def test_units_pass_systemd_analyze_verify(tmp_path: Path) -> None:
    cfg = config.load("penguin1")
    names = []
    python = tmp_path / "venv" / "bin" / "python"  # verify checks ExecStart exists: /opt/icefloe's, here
    python.parent.mkdir(parents=True)
    python.symlink_to(sys.executable)
    for name, text in deploy.units(cfg, deploy.ROBOTS / "penguin1.toml", python).items():
        if name.endswith("@.service"):
            name = name.replace("@.service", "@odometry.service")  # verify an instance of the template
        (tmp_path / name).write_text(text)
        names.append(f"./{name}")
    res = subprocess.run(["systemd-analyze", "verify", "--man=no", *names], capture_output=True, text=True,
                         cwd=tmp_path, timeout=60)
    assert res.returncode == 0, res.stdout + res.stderr


def test_ensure_lines_appends_only_what_is_missing(tmp_path: Path) -> None:
    boot = tmp_path / "config.txt"
    boot.write_text("# pi\nenable_uart=1\n")
    action = deploy.Action("boot", path=boot, ensure_lines=deploy.BOOT_LINES)
    assert action.do()
    assert not action.do()  # idempotent: nothing to change the second time
    lines = boot.read_text().splitlines()
    assert lines.count("enable_uart=1") == 1 and "dtparam=spi=on" in lines


def test_down_dry_run_removes_units(dry_run: str) -> None:
    res = subprocess.run(["./deploy/down.sh", "penguin1", "--dry-run"], capture_output=True, text=True,
                         cwd=ROOT, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "icefloe remove for robot 'penguin1'" in res.stdout and "(dry run: nothing changed)" in res.stdout


def test_the_robots_units_are_protected_from_the_students_programs() -> None:
    """Every unit of the robot in icefloe.slice (CPU weight over a user's session, memory kept), each
    process scored below a student's program for the OOM killer, hwbridge lowest; none made unkillable.
    That they hold against real hogs is the box's check (tests/test_box.py, test_6)."""
    cfg = config.load("penguin1")
    rendered = deploy.units(cfg, deploy.ROBOTS / "penguin1.toml", "/opt/icefloe/venv/bin/python")
    sliced = rendered["icefloe.slice"].splitlines()
    assert "CPUWeight=1000" in sliced and any(line.startswith("MemoryMin=") for line in sliced)
    scores = {}
    for name, text in rendered.items():
        if name.endswith(".service"):
            lines = text.splitlines()
            assert "Slice=icefloe.slice" in lines, name
            scores[name] = int(next(line for line in lines if line.startswith("OOMScoreAdjust=")).split("=")[1])
    assert all(-1000 < score < 0 for score in scores.values()), scores
    assert min(scores, key=scores.__getitem__) == "icefloe-hwbridge.service", scores
