"""The lock (uv.lock, exported to deploy/requirements/ by tools/lock.py; docs/DEVELOPING.md, "The lock").

Offline, in about two seconds: uv.lock is what pyproject.toml asks for and every export is what
uv.lock makes; every machine the lock covers gets a wheel of every package (no compiler: a fresh
Raspberry Pi OS has none), but for the apt-only ones; the pins are exact; the ranges a wheel
installs with have the upper bounds pyproject.toml explains; drift is told as doctor tells it.
Installing the built wheel with the lock's versions, and doctor naming a package installed at
another version, are tests/test_wheel.py's (they need a venv of their own).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from conftest import ROOT
from packaging.requirements import Requirement
from packaging.tags import compatible_tags, cpython_tags
from packaging.utils import canonicalize_name, parse_wheel_filename

from icefloe import lock

PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
UV_LOCK = tomllib.loads((ROOT / "uv.lock").read_text())
EXPORTS = ROOT / "deploy" / "requirements"
MACHINES = [(machine, python) for machine in ("x86_64", "aarch64") for python in ("3.11", "3.12", "3.13")]
GLIBC = 36
"""The oldest C library the lock must install on: Debian bookworm's and Raspberry Pi OS bookworm's 2.36."""
APT_ONLY = {"spidev": "icoboard"}
"""Packages PyPI has only as source, which a robot takes from apt (python3-spidev), and the one extra
that asks for them (for a machine with a compiler)."""


def test_the_lock_is_what_pyproject_asks_for_and_the_exports_are_the_locks() -> None:
    res = subprocess.run([sys.executable, "tools/lock.py", "--check"], cwd=ROOT, capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr


def test_there_is_an_export_for_each_extra_and_group() -> None:
    names = {p.stem for p in EXPORTS.glob("*.txt")}
    assert names == {"base", *PYPROJECT["project"]["optional-dependencies"], *PYPROJECT["dependency-groups"]}


def platform_tags(machine: str, python: str) -> set:
    version = tuple(int(p) for p in python.split("."))
    platforms = [*(f"manylinux_2_{m}_{machine}" for m in range(GLIBC, 16, -1)),
                 f"manylinux2014_{machine}", f"manylinux2010_{machine}", f"manylinux1_{machine}", f"linux_{machine}"]
    return set(cpython_tags(version, platforms=platforms)) | set(compatible_tags(version, platforms=platforms))


@pytest.mark.parametrize(("machine", "python"), MACHINES, ids=[f"{m}-py{p}" for m, p in MACHINES])
def test_every_locked_package_has_a_wheel_for_every_machine_the_lock_covers(machine: str, python: str) -> None:
    wheels = {(canonicalize_name(p["name"]), p["version"]): [w["url"].rsplit("/", 1)[1] for w in p.get("wheels", [])]
              for p in UV_LOCK["package"]}
    tags = platform_tags(machine, python)
    pins = lock.pins(environment=lock.environment(machine, python), directory=EXPORTS)
    missing = [name for name, pin in pins.items()
               if not any(set(parse_wheel_filename(f)[3]) & tags for f in wheels[name, pin.version])]
    assert sorted(missing) == sorted(APT_ONLY), f"no {machine} wheel for Python {python} (glibc 2.{GLIBC})"


def test_apt_only_packages_are_in_no_install_but_their_extra() -> None:
    """A fresh Debian or Raspberry Pi OS has no compiler: spidev (source only on PyPI) is in no
    export that deploy/setup.sh or the robot install takes."""
    for name, extra in APT_ONLY.items():
        holding = {p.stem for p in EXPORTS.glob("*.txt") if name in {pin.name for pin in lock.parse(p.read_text())}}
        assert holding == {extra}


def test_every_pin_is_exact_and_hashed() -> None:
    for path in EXPORTS.glob("*.txt"):
        for pin in lock.parse(path.read_text(), path.name):
            assert pin.hashes, f"{path.name}: {pin.name} has no hash"


def test_one_version_of_each_package_on_each_machine_across_every_export() -> None:
    for machine, python in MACHINES:
        lock.pins(environment=lock.environment(machine, python), directory=EXPORTS)  # raises if two disagree


def test_a_wheel_installs_with_ranges_and_the_upper_bounds_pyproject_explains() -> None:
    requirements = {canonicalize_name(Requirement(r).name): Requirement(r)
                    for r in PYPROJECT["project"]["dependencies"]}
    for name, bound in {"eclipse-zenoh": "<2", "numpy": "<3", "opencv-python-headless": "<6",
                        "aiohttp": "<3.15"}.items():
        assert bound in str(requirements[name].specifier), name
    assert not [r for r in requirements.values() if any(s.operator == "==" for s in r.specifier)]


def test_the_lock_knows_which_aiohttp_has_the_attribute_the_camera_stream_needs() -> None:
    """services/webapi/camera.py turns aiohttp's private ``_length_check`` off; the lock's aiohttp
    has it (tests/test_camera_http.py checks the wire), and pyproject's range ends before the next minor."""
    from aiohttp import web

    assert web.StreamResponse._length_check is True  # what ClosingStream turns off


def test_drift_names_a_different_version_a_missing_one_and_ignores_the_unknown(tmp_path: Path) -> None:
    export = tmp_path / "base.txt"
    export.write_text("numpy==2.4.6 ; sys_platform == 'linux' \\\n    --hash=sha256:" + "a" * 64 + "\n"
                      "    # via icefloe\n"
                      "msgspec==0.23.0 \\\n    --hash=sha256:" + "b" * 64 + "\n"
                      "uvloop==0.23.0 ; sys_platform == 'win32' \\\n    --hash=sha256:" + "c" * 64 + "\n")
    pins = lock.pins(["base"], lock.environment("aarch64"), tmp_path)
    assert sorted(pins) == ["msgspec", "numpy"]  # uvloop's marker is false here
    drifted = lock.drift(pins, {"numpy": "2.3.0", "students-own": "1.0"}, required=["msgspec", "numpy"])
    assert [str(d) for d in drifted] == ["numpy: lock 2.4.6, installed 2.3.0", "msgspec: lock 0.23.0, installed none"]


def test_a_requirement_that_is_not_exact_is_refused_naming_the_file() -> None:
    with pytest.raises(lock.LockError, match=r"^viz\.txt: rerun-sdk: a locked requirement has one exact version"):
        lock.parse("rerun-sdk>=0.22 \\\n    --hash=sha256:" + "a" * 64 + "\n", "viz.txt")


def test_this_checkouts_venv_is_as_locked() -> None:
    """The suite runs in the venv deploy/setup.sh made from the lock (tests/run.sh --newest, in its own
    copy, is the one run that is not)."""
    if os.environ.get("ICEFLOE_UNLOCKED") == "1":
        pytest.skip("tests/run.sh --newest: the newest versions, not the lock's")
    if Path(sys.prefix).resolve() != (ROOT / ".venv").resolve():
        pytest.skip(f"not the checkout's .venv ({sys.prefix}): tests/run.sh --newest, or another venv")
    drifted = lock.drift(lock.pins(), lock.installed(), required=lock.base_requirements())  # pip too
    assert not drifted, "\n".join(map(str, drifted))
