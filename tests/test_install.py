"""The robot install's fixes (issue 25), each on the defect a fresh machine showed:

1. no install needs a C compiler: spidev (PyPI has only its source) is in no install of a laptop
   or a PenguinPi robot;
2. the robot's venv sees apt's packages (``--system-site-packages``) and the plan installs the
   apt packages the config asks for (picamera2, spidev);
3. the services run from where their user can read (``/opt/icefloe/venv``, ``/etc/icefloe``),
   never from someone's home;

and what goes with them: ``remove`` undoes exactly what the install's manifest lists, a second
install changes nothing, the camera without picamera2 exits 2 with one line and the rest of the
robot runs, hwbridge says in one line what real time it is refused. The whole install, run for
real in a booted Debian root, is tests/test_box*.py's. About 30 s, most of it the `icefloe up` test (on a
loaded machine up to 2 min: `apt-cache policy` waits for the disk).
"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest
from conftest import ROOT, processes_naming, robot_config

from icefloe import config, deploy, paths
from icefloe.runtime import CANNOT_START

PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def requirements(extras: tuple[str, ...]) -> set[str]:
    """The names of the distributions an install of icefloe[extras] asks for (through icefloe[x] too)."""
    project = PYPROJECT["project"]
    names: set[str] = set()
    todo, seen = list(extras), set()
    reqs = list(project["dependencies"])
    while todo or reqs:
        if todo:
            extra = todo.pop()
            if extra not in seen:
                seen.add(extra)
                reqs += project["optional-dependencies"][extra]
            continue
        req = reqs.pop()
        name = re.split(r"[\s<>=!~;\[]", req, maxsplit=1)[0].lower()
        if name == "icefloe":  # the dev extra holds icefloe[gateware]
            todo += re.search(r"\[(.*)\]", req).group(1).split(",")  # type: ignore[union-attr]
        else:
            names.add(name)
    return names


# ---------------------------------------------------------------------- 1: no compiler needed


@pytest.mark.parametrize("extras", [(), ("viz",), ("robot",), ("dev",)], ids=["plain", "viz", "robot", "dev"])
def test_no_install_asks_for_spidev(extras: tuple[str, ...]) -> None:
    # PyPI has spidev only as source: a fresh Debian/Ubuntu without gcc and Python's headers fails to build it
    assert "spidev" not in requirements(extras)


def test_spidev_stays_reachable_as_an_extra() -> None:
    assert "gateware" in PYPROJECT["project"]["optional-dependencies"]  # (requirements() follows icefloe[...])
    assert "amaranth" in requirements(("dev",))
    assert any(r.startswith("spidev") for r in PYPROJECT["project"]["optional-dependencies"]["icoboard"])


# ---------------------------------------------------------------------- 2: apt's packages, seen by the venv


def test_the_robot_venv_sees_system_packages() -> None:
    plan = deploy.install_plan(config.load("penguin1"), paths.packaged("robots", "penguin1.toml"))
    venv = next(a for a in plan if "its own venv" in a.what)
    assert f"-m venv --system-site-packages {deploy.VENV}" in venv.describe()
    assert "not editable" in venv.describe()


def test_apt_packages_follow_the_config(tmp_path: Path) -> None:
    always, wanted = deploy.apt_packages(config.load("penguin1"))
    assert {"rt-tests", "gpiod", "i2c-tools", "python3-venv"} <= set(always)
    assert set(wanted) == {"python3-picamera2", "python3-libcamera"}  # camera.source = "picamera2"
    assert "camera" in wanted["python3-picamera2"]
    assert deploy.apt_packages(config.load("sim"))[1] == {}  # the simulated camera, the simulated board
    ico = tmp_path / "ico.toml"
    ico.write_text('extends = "sim-icoboard"\nname = "ico1"\n[board]\nbackend = "hardware"\n')
    assert set(deploy.apt_packages(config.load(ico))[1]) == {"python3-spidev"}
    no_camera = tmp_path / "nocam.toml"
    no_camera.write_text('extends = "penguin1"\nname = "blind1"\nservices = ["info", "hwbridge"]\n')
    assert deploy.apt_packages(config.load(no_camera))[1] == {}


@pytest.mark.skipif(shutil.which("apt-cache") is None, reason="not a Debian machine")
def test_apt_known_tells_a_package_apt_has_from_one_it_has_not() -> None:
    assert deploy.apt_known("dpkg")
    assert not deploy.apt_known("icefloe-no-such-package")


# ---------------------------------------------------------------------- 3: readable by the services' user


def test_the_units_run_nothing_from_a_home() -> None:
    cfg = config.load("penguin1")
    plan = deploy.install_plan(cfg, paths.packaged("robots", "penguin1.toml"))
    units = {a.path.name: a.content for a in plan if a.path is not None and a.path.parent == deploy.UNIT_DIR}
    assert len(units) == 6
    for name, text in units.items():
        if not name.endswith(".service"):
            continue
        exec_start = next(line for line in text.splitlines() if line.startswith("ExecStart="))
        python, *_, last = exec_start.removeprefix("ExecStart=").split()
        assert python == "/opt/icefloe/venv/bin/python", name
        if name == "icefloe-forkserver.service":   # it reads no config; its socket is in the runtime folder
            assert "--socket /run/icefloe/forkserver.sock" in exec_start and last == "icefloe", name
        else:
            assert last == "/etc/icefloe/robots/penguin1.toml", name
        assert "/home/" not in text and str(ROOT) not in text and sys.executable not in text, name


def test_the_config_installed_in_etc_still_resolves_its_extends(tmp_path: Path) -> None:
    # penguin1 extends the shipped sim.toml: copied alone to /etc/icefloe/robots/, it still loads
    copies = deploy.config_files(paths.packaged("robots", "penguin1.toml").resolve(), "penguin1")
    assert list(copies.values()) == [deploy.ROBOTS / "penguin1.toml"]
    # a config of one's own in a (0700) home that extends a file beside it: both are copied
    home = tmp_path / "home"
    home.mkdir()
    (home / "base.toml").write_text('extends = "penguin1"\n[hwbridge]\ndeadman_s = 0.3\n')
    (home / "mine.toml").write_text('extends = "base.toml"\nname = "mine1"\n')
    copies = deploy.config_files(home / "mine.toml", "mine1")
    assert {dest.name for dest in copies.values()} == {"mine1.toml", "base.toml"}
    etc = tmp_path / "etc"
    etc.mkdir()
    for src, dest in copies.items():
        shutil.copy(src, etc / dest.name)
    shutil.rmtree(home)  # the services' user cannot read it: nothing may come from there
    cfg = config.load(etc / "mine1.toml")
    assert (cfg.name, cfg.hwbridge.deadman_s, cfg.camera.source) == ("mine1", 0.3, "picamera2")


def test_a_config_extending_a_file_elsewhere_is_refused_in_one_line(tmp_path: Path) -> None:
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "base.toml").write_text('extends = "penguin1"\n')
    (tmp_path / "mine.toml").write_text('extends = "other/base.toml"\nname = "mine2"\n')
    with pytest.raises(config.ConfigError, match="cannot be installed"):
        deploy.config_files(tmp_path / "mine.toml", "mine2")


# ---------------------------------------------------------------------- the manifest and remove


def snapshot(top: Path) -> dict[str, str]:
    return {str(p.relative_to(top)): (p.read_text() if p.is_file() else "<dir>") for p in sorted(top.rglob("*"))}


def test_remove_undoes_exactly_what_the_install_added_and_installing_again_changes_nothing(tmp_path: Path) -> None:
    machine = tmp_path / "machine"
    boot = machine / "boot"
    boot.mkdir(parents=True)
    (boot / "config.txt").write_text("# the Pi's own\ndtparam=audio=on\nenable_uart=1\n")
    (boot / "cmdline.txt").write_text("console=serial0,115200 console=tty1 root=PARTUUID=1 rootwait\n")
    (machine / "etc").mkdir()
    (machine / "etc" / "theirs.conf").write_text("not ours\n")
    before = snapshot(machine)
    manifest = deploy.Manifest(tmp_path / "install.json")
    steps = [
        deploy.Action("folder", step=lambda m: deploy.make_dir(machine / "opt" / "icefloe", m, kind="tree")),
        deploy.Action("venv file", path=machine / "opt" / "icefloe" / "venv.txt", content="x\n"),
        deploy.Action("config", path=machine / "etc" / "icefloe" / "robots" / "r.toml", content='name = "r"\n'),
        deploy.Action("rules", path=machine / "etc" / "udev" / "99-icefloe.rules", content="rules\n"),
        deploy.Action("boot", path=boot / "config.txt", ensure_lines=deploy.BOOT_LINES),
        deploy.Action("cmdline", step=lambda m: deploy.edit_cmdline(boot / "cmdline.txt", 3, m)),
    ]
    assert all(step.do(manifest) for step in steps)
    assert "console=serial0" not in (boot / "cmdline.txt").read_text()
    assert (boot / "cmdline.txt").read_text().split()[-1] == "isolcpus=3"
    assert (boot / "config.txt").read_text().count("enable_uart=1") == 1  # it was there: not added twice
    assert not any(step.do(manifest) for step in steps)  # a second install changes nothing
    saved = deploy.Manifest.load(tmp_path / "install.json")
    assert saved.entries == manifest.entries
    assert ["line", str(boot / "config.txt"), "enable_uart=1"] not in saved.entries  # not ours to remove
    for action in deploy.remove_plan(saved):
        action.do(saved)
    assert snapshot(machine) == before


def test_the_remove_plan_has_a_step_for_every_kind_of_addition() -> None:
    added = [["apt", "rt-tests"], ["tree", "/opt/icefloe"], ["group", "spi"], ["user", "icefloe"],
             ["dir", "/etc/icefloe"], ["file", "/etc/icefloe/robots/penguin1.toml"],
             ["credentials", "/etc/icefloe/penguin1.credentials"], ["unit", "icefloe.target"],
             ["line", "/boot/firmware/config.txt", "enable_uart=1"],
             ["cmdline+", "/boot/firmware/cmdline.txt", "isolcpus=3"],
             ["cmdline-", "/boot/firmware/cmdline.txt", "console=serial0,115200"]]
    plan = "".join(a.describe() for a in deploy.remove_plan(deploy.Manifest(None, added)))
    for needle in ("systemctl disable", "icefloe.target", "rm -f /etc/icefloe/robots/penguin1.toml",
                   "userdel --remove icefloe", "groupdel spi", "rm -rf /opt/icefloe", "rmdir /etc/icefloe",
                   "remove the line enable_uart=1", "remove isolcpus=3", "put back console=serial0,115200",
                   "keep the robot's credentials", "chown root:root /etc/icefloe/penguin1.credentials"):
        assert needle in plan, needle
    assert "rt-tests" not in plan  # apt packages stay
    purged = "".join(a.describe() for a in deploy.remove_plan(deploy.Manifest(None, added), purge=True))
    assert "rm -f /etc/icefloe/penguin1.credentials" in purged


def test_flags_reach_the_install_through_up_sh() -> None:
    res = subprocess.run(["./deploy/up.sh", "penguin1", "--dry-run", "--no-boot-config"], capture_output=True,
                         text=True, cwd=ROOT, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "/boot/firmware" not in res.stdout and "icefloe install for robot 'penguin1'" in res.stdout


def test_installing_on_a_machine_without_a_boot_config_says_which_flag_in_one_line() -> None:
    if deploy.BOOT_CONFIG.exists():
        pytest.skip("this machine has a Raspberry Pi boot config")
    res = subprocess.run([sys.executable, "-m", "icefloe.deploy", "install", "penguin1"], capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 78 and res.stdout == "", res.stdout
    assert res.stderr.count("\n") == 1 and "--no-boot-config" in res.stderr


# ---------------------------------------------------------------------- the camera without picamera2


PICAMERA2 = importlib.util.find_spec("picamera2") is not None


@pytest.mark.skipif(PICAMERA2, reason="picamera2 is installed here")
def test_the_camera_without_picamera2_exits_2_with_one_line_naming_the_apt_package(tmp_path: Path) -> None:
    cfg = robot_config(tmp_path, "nocam", '[camera]\nsource = "picamera2"\n')
    res = subprocess.run([sys.executable, "-m", "icefloe.services.camera", "--config", str(cfg)],
                         capture_output=True, text=True, timeout=60)
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert res.returncode == CANNOT_START, res.stderr
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert "apt install python3-picamera2" in lines[0] and "picamera2" in lines[0]


@pytest.mark.skipif(PICAMERA2, reason="picamera2 is installed here")
def test_icefloe_up_runs_the_rest_of_the_robot_when_the_camera_cannot_start(tmp_path: Path) -> None:
    cfg = robot_config(tmp_path, "upcam", 'services = ["info", "camera"]\n[camera]\nsource = "picamera2"\n')
    log = tmp_path / "up.log"
    with log.open("w") as out:
        up = subprocess.Popen([sys.executable, "-m", "icefloe.cli", "up", str(cfg), "--no-viz"], stdout=out,
                              stderr=subprocess.STDOUT, cwd=ROOT, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while "it cannot start as configured" not in log.read_text() and time.monotonic() < deadline:
            assert up.poll() is None, log.read_text()
            time.sleep(0.2)
        text = log.read_text()
        assert "apt install python3-picamera2" in text and "it cannot start as configured" in text, text
        time.sleep(3)  # had it been restarted (1 s back-off) or had the robot stopped, it would show by now
        assert up.poll() is None, log.read_text()
        ours = set(processes_naming(str(cfg)))  # (other tests on this machine run services too)
        assert ours & set(processes_naming("icefloe.services.info")), log.read_text()
        assert not ours & set(processes_naming("icefloe.services.camera")), log.read_text()
        assert log.read_text().count("apt install python3-picamera2") == 1
    finally:
        up.send_signal(signal.SIGINT)
        try:
            up.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(up.pid, signal.SIGKILL)
            raise


# ---------------------------------------------------------------------- hwbridge without real time


@pytest.mark.skipif(sys.platform != "linux", reason="Linux scheduling")
def test_hwbridge_says_in_one_line_what_real_time_it_is_refused() -> None:
    code = (
        "import os, resource\n"
        "from icefloe.services.hwbridge.rt import make_realtime\n"
        "resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))\n"
        "resource.setrlimit(resource.RLIMIT_MEMLOCK, (0, 0))\n"
        "if os.geteuid() == 0:\n"
        "    os.setgroups([]); os.setgid(65534); os.setuid(65534)  # nobody: no CAP_SYS_NICE, no CAP_IPC_LOCK\n"
        "said = []\n"
        "make_realtime(80, -1, lambda kind, text: said.append(text))\n"
        "print(repr(said))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}, cwd="/")
    assert res.returncode == 0, res.stderr
    said = eval(res.stdout)
    assert len(said) == 1, said
    assert "SCHED_FIFO priority 80" in said[0] and "mlockall" in said[0] and "runs anyway" in said[0]
