"""The icefloe wheel, as a laptop or a lab machine gets it: built, installed into a fresh venv
outside any checkout, and run from a folder that has no checkout.

* Every file of the package folders is in the wheel (robot configs, worlds, the ACL template,
  JSON Schemas, systemd templates, a service's ``static/`` files), or is named below as a file
  only a checkout needs.
* It installs with ranges (a library must not pin); installed as the README says, with the lock's
  versions of the ``viz`` extra that it carries (from the package registry; pip's cache where it
  has one), nothing differs from the lock, and ``icefloe doctor`` names a package installed at
  another version. ``icefloe up`` runs the simulated robot (a user's own ``sim.toml`` in
  ``~/.config/icefloe/robots/`` overrides the shipped one by name), ``icefloe viz --connect``
  records it, Ctrl-C stops everything; ``icefloe router --lab DIR`` guards a lab.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import tomllib
import zipfile
from pathlib import Path

import pytest
from conftest import ROOT, free_port, processes_naming
from packaging.requirements import Requirement

NOT_SHIPPED = {
    "deploy/up.sh": "sets up and runs a checkout's .venv",
    "deploy/down.sh": "undoes deploy/up.sh on a robot",
    "deploy/setup.sh": "sourced by deploy/up.sh and tests/run.sh",
    "deploy/box.sh": "boots a checkout's robot in a box (docs/box.md)",
    "deploy/box/NEEDS.md": "notes between the box's and the install's engineers",
    "schemas/README.md": "the contract's documentation, read in the repository",
}
"""Files of the package folders that only a checkout needs, and why."""


def package_dirs() -> dict[str, str]:
    """Package -> source folder, as pyproject.toml maps them (``icefloe.share`` -> ``deploy``)."""
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    return pyproject["tool"]["setuptools"]["package-dir"]


def source_files(folder: str) -> list[str]:
    """The files of a folder that belong to the project: tracked or new, not ignored by git."""
    if (ROOT / ".git").exists():
        out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", folder],
                             cwd=ROOT, capture_output=True, text=True, check=True).stdout
        return [f for f in out.splitlines() if (ROOT / f).is_file()]
    return [p.relative_to(ROOT).as_posix() for p in (ROOT / folder).rglob("*")
            if p.is_file() and "__pycache__" not in p.parts]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``pip wheel --no-deps`` of a clean copy of the source: a checkout's own build/ folder can
    hold files that no longer exist, and they would end up in the wheel."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
        ".git", ".venv", "build", "*.egg-info", "__pycache__", ".*_cache", "node_modules", "*.rrd", "out"))
    t0 = time.monotonic()
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp / "dist"), str(src)],
                   check=True, capture_output=True, timeout=300)
    print(f"built the wheel in {time.monotonic() - t0:.1f} s")
    return next((tmp / "dist").glob("icefloe-*.whl"))


def test_the_wheel_holds_every_file_a_user_needs(wheel: Path) -> None:
    inside = set(zipfile.ZipFile(wheel).namelist())
    missing = []
    for package, folder in package_dirs().items():
        for path in source_files(folder):
            where = "/".join([*package.split("."), *Path(path).relative_to(folder).parts])
            if path not in NOT_SHIPPED and where not in inside:
                missing.append(path)
    assert missing == [], (f"not in the wheel: {missing}; add them to [tool.setuptools.package-data] in "
                           "pyproject.toml (or, if only a checkout needs them, to NOT_SHIPPED here)")
    for shipped in ("icefloe/share/robots/sim.toml", "icefloe/share/worlds/lab.toml",
                    "icefloe/share/zenoh/acl/owner.json5", "icefloe/share/systemd/icefloe@.service",
                    "icefloe/schemas/json/Pose.json"):
        assert shipped in inside
    assert not [n for n in inside if n.startswith(("tests/", "bench/", "examples/", "docs/"))]
    # the lock travels with the wheel, and the wheel itself asks for ranges, not the lock's pins
    assert {f"icefloe/share/requirements/{e}.txt" for e in ("base", "viz", "robot", "build")} <= inside
    metadata = next(n for n in inside if n.endswith(".dist-info/METADATA"))
    requires = [Requirement(line.removeprefix("Requires-Dist:"))
                for line in zipfile.ZipFile(wheel).read(metadata).decode().splitlines()
                if line.startswith("Requires-Dist:")]
    assert requires and not [r for r in requires if any(s.operator in ("==", "===") for s in r.specifier)]


# ---------------------------------------------------------------------------- installed, and run


class Installed:
    """A venv with the wheel in it, and a home folder with no checkout anywhere near it."""

    def __init__(self, venv: Path, home: Path) -> None:
        self.venv, self.home = venv, home
        self.cwd = home / "work"
        self.cwd.mkdir(parents=True)
        # Only what a fresh login has: no PYTHONPATH, no other venv, nothing of the checkout.
        self.env = {"PATH": f"{venv / 'bin'}:/usr/local/bin:/usr/bin:/bin", "HOME": str(home),
                    "LANG": "C.UTF-8", "PYTHONUNBUFFERED": "1", "TMPDIR": os.environ.get("TMPDIR", "/tmp")}

    def run(self, *args: str, timeout: float = 60.0, check: bool = True) -> subprocess.CompletedProcess[str]:
        res = subprocess.run(list(args), cwd=self.cwd, env=self.env, capture_output=True, text=True,
                             timeout=timeout)
        if check:
            assert res.returncode == 0, f"{' '.join(args)}: exit {res.returncode}\n{res.stdout}\n{res.stderr}"
        return res

    def start(self, log: Path, *args: str) -> subprocess.Popen[bytes]:
        with open(log, "wb") as out:
            return subprocess.Popen(list(args), cwd=self.cwd, env=self.env, stdout=out, stderr=subprocess.STDOUT,
                                    start_new_session=True)


def wait_for_text(log: Path, text: str, proc: subprocess.Popen[bytes], timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while text not in log.read_text(errors="replace"):
        assert proc.poll() is None, f"exited ({proc.returncode}) before saying {text!r}:\n{log.read_text()}"
        assert time.monotonic() < deadline, f"no {text!r} within {timeout:.0f} s:\n{log.read_text()}"
        time.sleep(0.2)


def stop(proc: subprocess.Popen[bytes], timeout: float = 30.0) -> int:
    """SIGINT (Ctrl-C), and the exit status; killed (and failed) if it does not exit."""
    proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        raise AssertionError(f"did not exit within {timeout:.0f} s of SIGINT") from None


def pip(venv: Path, *args: str) -> None:
    """This interpreter's pip, installing into ``venv`` (``--python``): a venv needs no pip of its own."""
    res = subprocess.run([sys.executable, "-m", "pip", "--python", str(venv / "bin" / "python"), *args],
                         capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stdout + res.stderr


def locked_viz(venv: Path) -> Path:
    """The lock's ``viz`` export as the installed wheel carries it (the README's second pip command)."""
    return next(venv.glob("lib/python3*/site-packages/icefloe/share/requirements/viz.txt"))


@pytest.fixture(scope="module")
def installed(wheel: Path, tmp_path_factory: pytest.TempPathFactory):
    """The wheel, then the lock's versions of its dependencies with ``[viz]``, in a new venv, as the
    README says (removed afterwards: ~1 GB)."""
    tmp = tmp_path_factory.mktemp("installed")
    venv = tmp / "venv"
    t0 = time.monotonic()
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    pip(venv, "install", "-q", "--no-deps", str(wheel))
    pip(venv, "install", "-q", "--require-hashes", "-r", str(locked_viz(venv)))
    print(f"venv and install of {wheel.name} with the lock's [viz]: {time.monotonic() - t0:.1f} s")
    yield Installed(venv, tmp / "home")
    shutil.rmtree(venv, ignore_errors=True)


@pytest.mark.slow
@pytest.mark.timeout(900)  # with the venv and the install, if it runs alone
def test_installed_as_locked_and_doctor_names_a_package_at_another_version(installed: Installed) -> None:
    assert installed.run("python", "-m", "icefloe.lock").stdout.startswith("every installed package is as locked")
    nowhere = f"tcp/127.0.0.1:{free_port()}"   # no robot: doctor's bus checks fail fast, its local ones run
    pip(installed.venv, "install", "-q", "--no-deps", "pyserial==3.4")
    try:
        doctor = installed.run("icefloe", "doctor", "--connect", nowhere, check=False, timeout=60)
        assert doctor.returncode == 1
        lines = [line for line in doctor.stdout.splitlines() if line.startswith("package ")]
        assert len(lines) == 1 and lines[0].startswith("package pyserial: lock 3.5, installed 3.4: "), doctor.stdout
        assert installed.run("python", "-m", "icefloe.lock", check=False).stdout.splitlines()[0] == \
            "pyserial: lock 3.5, installed 3.4"
    finally:   # put the lock's back, as doctor's line says
        pip(installed.venv, "install", "-q", "--require-hashes", "-r", str(locked_viz(installed.venv)))
    doctor = installed.run("icefloe", "doctor", "--connect", nowhere, check=False, timeout=60)
    assert not [line for line in doctor.stdout.splitlines() if line.startswith("package ")], doctor.stdout


@pytest.mark.slow
@pytest.mark.timeout(900)  # with the venv and the install (~1 min)
def test_installed_anywhere_it_runs_the_simulated_robot_and_a_viewer(installed: Installed) -> None:
    site = installed.run("python", "-c", "import icefloe; print(icefloe.__file__)").stdout.strip()
    assert site.startswith(str(installed.venv)) and str(ROOT) not in site, site
    shipped = json.loads(installed.run("icefloe", "config", "penguin1").stdout)
    assert shipped["source"].startswith(str(installed.venv)) and shipped["board"]["backend"] == "hardware"

    # A robot installed from the wheel: its units run /opt/icefloe/venv (icefloe/deploy.py), not a home.
    plan = installed.run("python", "-m", "icefloe.deploy", "install", "penguin1", "--dry-run").stdout
    exec_start = ("ExecStart=/opt/icefloe/venv/bin/python -m icefloe.forkserver start --socket "
                  "/run/icefloe/forkserver.sock icefloe.services.hwbridge --config /etc/icefloe/robots/")
    assert exec_start in plan, plan

    # The user's own sim.toml overrides the shipped one by name; it extends the shipped one.
    port, web = free_port(), free_port()
    name = f"wheel{port}"
    mine = installed.home / ".config" / "icefloe" / "robots" / "sim.toml"
    mine.parent.mkdir(parents=True)
    mine.write_text(f'extends = "sim"\nname = "{name}"\nrun_dir = "{installed.home / "run"}"\n\n'
                    f"[webapi]\nport = {web}\n\n"
                    f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\nconnect = ["tcp/127.0.0.1:{port}"]\n')
    resolved = json.loads(installed.run("icefloe", "config").stdout)
    assert (resolved["name"], resolved["source"], resolved["board"]["kind"]) == (name, str(mine), "penguinpi")

    log = installed.home / "up.log"
    t0 = time.monotonic()
    up = installed.start(log, "icefloe", "up")   # the simulated robot: no name needed
    try:
        services = ["router", "info", "sim", "hwbridge", "odometry", "localizer", "camera", "power", "oled",
                    "webapi"]
        deadline = time.monotonic() + 90
        while True:
            status = installed.run("icefloe", "status", check=False).stdout.split()
            if set(services) <= set(status):
                break
            assert up.poll() is None, log.read_text()
            assert time.monotonic() < deadline, f"not all alive: {status}\n{log.read_text()}"
            time.sleep(1.0)
        print(f"icefloe up: every service alive after {time.monotonic() - t0:.1f} s")
        poses = installed.run("icefloe", "echo", "odom/pose", "--count", "3", timeout=30).stdout.splitlines()
        assert len(poses) == 3 and {"x", "y", "theta"} <= set(json.loads(poses[0]))

        # A laptop's view: viz records the robot while the README's twist drives it in a circle.
        rrd = installed.home / "run.rrd"
        viz = installed.start(installed.home / "viz.log", "icefloe", "viz", "--connect", f"tcp/127.0.0.1:{port}",
                              "--save", str(rrd), "--duration", "8")
        installed.run("icefloe", "pub", "cmd/twist", '{"v": 0.1, "w": 0.5}', "--rate", "10", "--count", "50")
        assert viz.wait(60) == 0, (installed.home / "viz.log").read_text()
        print(f"icefloe viz: recorded {rrd.stat().st_size / 1e6:.1f} MB, {time.monotonic() - t0:.1f} s after up")
        check = ("import json, sys; from icefloe.services.viz.readback import read_rrd; "
                 "d = read_rrd(sys.argv[1]); print(json.dumps({k: len(v.get('log_time', [])) for k, v in d.items()}))")
        rows = json.loads(installed.run("python", "-c", check, str(rrd)).stdout)
        for entity in ("map/odom", "map/loc", "camera/image", "wheels/left/measured", "battery/voltage/filtered"):
            assert rows.get(f"/robots/{name}/{entity}", 0) > 0, (entity, sorted(rows))
        assert stop(up) == 0, log.read_text()
    finally:
        if up.poll() is None:
            os.killpg(up.pid, signal.SIGKILL)
            up.wait()
    text = log.read_text()
    assert "all stopped" in text and "Traceback" not in text, text
    time.sleep(0.5)
    assert processes_naming(str(mine)) == [], "a service outlived Ctrl-C"


@pytest.mark.slow
@pytest.mark.timeout(900)  # with the venv and the install, if it runs alone
def test_installed_anywhere_it_runs_a_lab_router(installed: Installed, tmp_path: Path) -> None:
    lab_port = free_port()
    lab = tmp_path / "lab"
    lab.mkdir(mode=0o700)
    robots = {}
    for robot in ("penguinA", "penguinB"):   # each robot makes its credentials (deploy/up.sh does)
        robots[robot] = tmp_path / f"{robot}.toml"
        robots[robot].write_text(
            f'extends = "sim"\nname = "{robot}{lab_port}"\nrun_dir = "{tmp_path / robot}"\n\n'
            f'[zenoh]\nlisten = []\nconnect = ["tcp/127.0.0.1:{lab_port}"]\naccess_control = true\n'
            f'credentials = "{lab / robot}.credentials"\n')
        installed.run("icefloe", "credentials", str(robots[robot]))
    lab_toml = tmp_path / "lab.toml"
    lab_toml.write_text(f'name = "lab"\nrun_dir = "{tmp_path / "run-lab"}"\n\n'
                        f'[zenoh]\nlisten = ["tcp/127.0.0.1:{lab_port}"]\nconnect = []\n')
    log = tmp_path / "router.log"
    router = installed.start(log, "icefloe", "router", str(lab_toml), "--lab", str(lab))
    info = None
    try:
        wait_for_text(log, "listening on", router, 30)
        assert f"lab router for penguinA{lab_port}, penguinB{lab_port}" in log.read_text()
        info = installed.start(tmp_path / "info.log", "python", "-m", "icefloe.services.info",
                               "--config", str(robots["penguinA"]))
        endpoint = f"tcp/127.0.0.1:{lab_port}"
        deadline = time.monotonic() + 30
        while f"penguinA{lab_port}: info" not in (seen := installed.run(
                "icefloe", "status", "--connect", endpoint, check=False).stdout):    # as the guest
            assert time.monotonic() < deadline, seen
            time.sleep(0.5)
        answer = installed.run("icefloe", "query", "info", "--connect", endpoint,
                               "--credentials", f"{lab / 'penguinA'}.credentials")
        assert json.loads(answer.stdout)["name"] == f"penguinA{lab_port}"
        guest = installed.run("icefloe", "query", "info", "--robot", f"penguinA{lab_port}", "--connect", endpoint,
                              "--timeout", "10")
        # the guest may ask the read-only queryables (info); what it may not do is tests/test_security.py's
        assert json.loads(guest.stdout)["name"] == f"penguinA{lab_port}"
    finally:
        for proc in (info, router):
            if proc is not None and proc.poll() is None:
                stop(proc)
