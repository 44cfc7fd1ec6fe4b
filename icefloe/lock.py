"""The lock as an installed icefloe carries it: the exact version of every dependency, with the hash
of every file of it, for every machine the lock covers (docs/DEVELOPING.md, "The lock").

``uv.lock`` is made by ``tools/lock.py`` and exported for pip as ``deploy/requirements/<extra>.txt``
(shipped as ``icefloe/share/requirements/``): one requirement a package, ``name==version ; marker``
with its ``--hash=sha256:...`` options. From them:

* `drift`: the installed packages whose version is not the lock's (``icefloe doctor``);
* `wheelhouse_problems`: why a folder of wheels cannot install the lock (the robot install
  refuses such a folder, and the box's wheelhouse is checked with it);
* `pins`: the lock's requirements that apply to a machine (this one, or another: an arm64 box).
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import platform
import re
import sys
from collections.abc import Collection, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from packaging.markers import Marker
from packaging.requirements import Requirement
from packaging.tags import Tag
from packaging.utils import canonicalize_name, parse_wheel_filename

from . import paths
from .errors import IcefloeError

HASH = re.compile(r"--hash=sha256:([0-9a-f]{64})")


TOOLS = ("build",)
"""Exports of what installs icefloe (pip, setuptools), not of what it runs with: a venv made by
hand keeps its own pip, and that is no drift (`runtime_pins`)."""


class LockError(IcefloeError):
    """The lock, or something checked against it, is not as it must be (the message says which)."""


@dataclass(frozen=True)
class Pin:
    """One locked requirement: a package at one version, on the machines its marker selects."""

    name: str
    """The package's name, normalized (``luma-oled``, not ``luma.oled``)."""
    version: str
    marker: Marker | None
    hashes: frozenset[str]
    """The sha256 of every file of this version the lock allows (wheels and sdist, every platform)."""

    def applies(self, environment: Mapping[str, str] | None = None) -> bool:
        return self.marker is None or self.marker.evaluate(dict(environment) if environment else None)

    def requirement(self) -> str:
        """The pin as pip reads it, with its hashes (a requirements file's entry)."""
        return f"{self.name}=={self.version}" + "".join(f" --hash=sha256:{h}" for h in sorted(self.hashes))


def folder() -> Path:
    """Where the installed icefloe keeps its exports (``deploy/requirements`` in a checkout)."""
    return paths.packaged("requirements")


def parse(text: str, source: str = "lock") -> list[Pin]:
    """The pins of one export's text; `LockError` naming the file and line for anything else."""
    out = []
    # An entry runs over continued lines (a trailing backslash); comments start with "#".
    for entry in re.sub(r"\\\n", " ", text).splitlines():
        entry = entry.split(" #", 1)[0].strip()
        if not entry or entry.startswith("#"):
            continue
        spec = HASH.sub("", entry).strip()
        try:
            req = Requirement(spec)
        except ValueError as exc:
            raise LockError(f"{source}: not a requirement: {spec[:80]!r} ({exc})") from None
        versions = [s.version for s in req.specifier if s.operator == "=="]
        if len(versions) != 1 or len(req.specifier) != 1:
            raise LockError(f"{source}: {req.name}: a locked requirement has one exact version (==), not "
                            f"{str(req.specifier) or 'none'!r}")
        out.append(Pin(canonicalize_name(req.name), versions[0], req.marker, frozenset(HASH.findall(entry))))
    return out


def read(names: Iterable[str] | None = None, directory: Path | None = None) -> list[Pin]:
    """The pins of the named exports (``"robot"`` for ``robot.txt``), or of every export."""
    directory = directory or folder()
    files = [directory / f"{n}.txt" for n in names] if names is not None else sorted(directory.glob("*.txt"))
    if not files:
        raise LockError(f"{directory}: no lock (deploy/requirements/*.txt); this icefloe was built without one")
    out = []
    for f in files:
        try:
            out += parse(f.read_text(), f.name)
        except FileNotFoundError:
            raise LockError(f"{f}: no such export of the lock (extras have one each: "
                            f"{', '.join(p.stem for p in sorted(directory.glob('*.txt')))})") from None
    return out


def pins(names: Iterable[str] | None = None, environment: Mapping[str, str] | None = None,
         directory: Path | None = None) -> dict[str, Pin]:
    """Package name -> the lock's pin for a machine (default: this one; see `environment`)."""
    out: dict[str, Pin] = {}
    for pin in read(names, directory):
        if pin.applies(environment):
            if pin.name in out and out[pin.name].version != pin.version:
                raise LockError(f"{pin.name}: the lock's exports disagree on its version here "
                                f"({out[pin.name].version} and {pin.version}): run tools/lock.py")
            out[pin.name] = pin
    return out


def runtime_pins() -> dict[str, Pin]:
    """The lock's pins on this machine for what icefloe runs with (every export but `TOOLS`)."""
    return pins(sorted(p.stem for p in folder().glob("*.txt") if p.stem not in TOOLS))


def environment(machine: str, python: str = "3.11") -> dict[str, str]:
    """The marker values of another Linux machine (``aarch64``, Python ``3.11``): an arm64 box."""
    return {"sys_platform": "linux", "platform_system": "Linux", "os_name": "posix",
            "platform_machine": machine, "python_version": python, "python_full_version": f"{python}.0",
            "implementation_name": "cpython", "platform_python_implementation": "CPython",
            "platform_release": "", "platform_version": "", "implementation_version": f"{python}.0",
            "extra": ""}


def own_path() -> list[str]:
    """Where this Python's own packages are: in a venv, the venv's folders only. A robot's venv also
    sees the system's packages (apt's picamera2 and spidev, ``--system-site-packages``), which apt,
    not the lock, keeps."""
    if sys.prefix == sys.base_prefix:
        return list(sys.path)
    return [p for p in sys.path if Path(p or ".").resolve().is_relative_to(Path(sys.prefix).resolve())]


def installed(path: Iterable[str] | None = None) -> dict[str, str]:
    """Package name -> the version Python imports: the first of each name along ``path`` (default
    `own_path`)."""
    out: dict[str, str] = {}
    for dist in importlib.metadata.distributions(path=list(path) if path is not None else own_path()):
        name = dist.metadata["Name"]
        if name:
            out.setdefault(canonicalize_name(name), dist.version)
    return out


@dataclass(frozen=True)
class Drift:
    name: str
    locked: str
    installed: str
    """The installed version, or "" when a package the lock needs here is not installed."""

    def __str__(self) -> str:
        return f"{self.name}: lock {self.locked}, installed {self.installed or 'none'}"


def drift(locked: Mapping[str, Pin], have: Mapping[str, str], required: Iterable[str] = ()) -> list[Drift]:
    """Each installed package whose version is not the lock's, and each of ``required`` (package
    names) that is missing. Packages the lock does not know (a student's own) are not drift."""
    out = [Drift(n, p.version, have[n]) for n, p in sorted(locked.items()) if n in have and have[n] != p.version]
    out += [Drift(n, locked[n].version, "") for n in sorted(set(required)) if n in locked and n not in have]
    return out


def base_requirements() -> set[str]:
    """The package names icefloe itself needs on every machine (the lock's ``base`` export)."""
    return set(pins(["base"]))


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()


def wheelhouse_problems(directory: Path, locked: Mapping[str, Pin], tags: Collection[Tag] | None = None) -> list[str]:
    """Why ``directory`` cannot install ``locked`` with nothing downloaded: each pin with no file
    of the lock's version, or whose file's hash is not one the lock lists, or (given the ``tags`` of the
    machine that installs: `packaging.tags.sys_tags`) whose files the lock lists are all wheels for
    another machine or Python (the lock lists every machine's). Empty: it can."""
    files: dict[str, list[Path]] = {}
    for f in sorted(directory.iterdir()) if directory.is_dir() else []:
        if f.suffix == ".whl":
            files.setdefault(canonicalize_name(parse_wheel_filename(f.name)[0]), []).append(f)
        elif f.name.endswith((".tar.gz", ".zip")):
            files.setdefault(canonicalize_name(re.split(r"-\d", f.name, maxsplit=1)[0]), []).append(f)
    if not directory.is_dir():
        return [f"{directory}: no such folder"]
    problems = []
    for name, pin in sorted(locked.items()):
        ours = files.get(name, [])
        if not ours:
            problems.append(f"{name} {pin.version}: no file in {directory}")
            continue
        listed = [f for f in ours if sha256(f) in pin.hashes]
        if not listed:
            problems.append(f"{name} {pin.version}: {', '.join(f.name for f in ours)} is not a file the lock "
                            f"lists (another version, or another build)")
        elif tags is not None and not any(installable(f, tags) for f in listed):
            problems.append(f"{name} {pin.version}: {', '.join(f.name for f in listed)} is for another machine "
                            "or Python, not this one")
    return problems


def installable(path: Path, tags: Collection[Tag]) -> bool:
    """A wheel made for one of ``tags`` (a machine's), or a source archive (pip builds it there)."""
    return path.suffix != ".whl" or not parse_wheel_filename(path.name)[3].isdisjoint(tags)


def this_machine() -> str:
    """What the lock calls this machine, for messages (``Linux x86_64, Python 3.11``)."""
    return f"{platform.system()} {platform.machine()}, Python {platform.python_version()}"


ROBOT_EXPORTS = ("build", "planner", "robot")
"""What a robot install takes from the lock: pip and setuptools, what plans it, the robot's extra."""
GLIBC = 36
"""The C library of Debian and Raspberry Pi OS bookworm (2.36): the newest manylinux a robot's wheel may need."""


def download_wheelhouse(directory: Path, machine: str, python: str = "3.11",
                        names: Iterable[str] = ROBOT_EXPORTS) -> list[str]:
    """Download into ``directory`` the lock's file of every package a robot of ``machine`` installs
    (wheels only: nothing is built for another machine), and return `wheelhouse_problems` (empty: it
    is complete). pip evaluates a requirement's markers for the machine it runs on, not for
    ``--platform``: so they are evaluated here, and pip gets exact pins with their hashes."""
    import subprocess
    import tempfile

    chosen = pins(names, environment(machine, python))
    tag = python.replace(".", "")
    platforms = [f"--platform=manylinux_2_{m}_{machine}" for m in range(GLIBC, 16, -1)]
    with tempfile.NamedTemporaryFile("w", suffix=".txt") as requirements:
        requirements.write("".join(f"{pin.requirement()}\n" for _, pin in sorted(chosen.items())))
        requirements.flush()
        r = subprocess.run([sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--require-hashes",
                            "-r", requirements.name, "--dest", str(directory), "--only-binary=:all:", *platforms,
                            f"--platform=manylinux2014_{machine}", f"--python-version={python}",
                            "--implementation=cp", f"--abi=cp{tag}"], capture_output=True, text=True)
    if r.returncode != 0:
        raise LockError(f"pip download for {machine}, Python {python}: "
                        + next((line for line in r.stderr.splitlines() if line.startswith("ERROR")), r.stderr[-300:]))
    return wheelhouse_problems(directory, {n: p for n, p in chosen.items() if n not in APT})


APT = {"spidev"}
"""Packages a robot takes from apt, not from a wheelhouse (PyPI has only their source)."""


def main(argv: list[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m icefloe.lock", description=(
        "Print each installed package that differs from the lock (exit 1 if any); or, with --wheelhouse, "
        "download the lock's files of a robot's packages, for installing robots with nothing downloaded."))
    parser.add_argument("--wheelhouse", metavar="DIR",
                        help="download into DIR the lock's wheel of every package a robot installs "
                             "(./deploy/up.sh ROBOT --wheelhouse=DIR installs from it)")
    parser.add_argument("--machine", default="aarch64", choices=("aarch64", "x86_64"),
                        help="with --wheelhouse: the robots' machine (default aarch64, a Raspberry Pi)")
    parser.add_argument("--python", default="3.11", help="with --wheelhouse: the robots' Python (bookworm: 3.11)")
    args = parser.parse_args(argv)
    if args.wheelhouse:
        directory = Path(args.wheelhouse).expanduser()
        directory.mkdir(parents=True, exist_ok=True)
        problems = download_wheelhouse(directory, args.machine, args.python)
        for line in problems:
            print(line, file=sys.stderr)
        print(f"{directory}: {'INCOMPLETE' if problems else 'the lock of'} a robot's packages for Linux "
              f"{args.machine}, Python {args.python}")
        return 1 if problems else 0
    drifted = drift(runtime_pins(), installed(), required=base_requirements())
    for d in drifted:
        print(d)
    print(f"{len(drifted)} of the installed packages differ from the lock ({this_machine()})"
          if drifted else f"every installed package is as locked ({this_machine()})")
    return 1 if drifted else 0


if __name__ == "__main__":
    sys.exit(main())
