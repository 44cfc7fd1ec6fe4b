"""Install (or remove) an icefloe robot on its Raspberry Pi: what `deploy/up.sh` does on a robot.

    python -m icefloe.deploy install CONFIG [--dry-run] [--no-boot-config] [--source SRC] [--wheelhouse DIR]
    python -m icefloe.deploy remove CONFIG [--dry-run] [--purge]          (deploy/down.sh)

Every step is an `Action`: a description, and a command, a file to write or a small Python
step. ``--dry-run`` prints them all and changes nothing. The steps are idempotent: a file with
the same content is not written again, a user, group or line that is there is not added again,
and a venv that holds this very source is not installed again; a second install says
"0 steps changed something".

The services run from where their user (``icefloe``, a system user) can read, never from
someone's home (Debian makes homes 0700): a venv in `VENV` made with
``--system-site-packages`` (Raspberry Pi OS ships picamera2, libcamera's bindings and spidev
as apt packages only), icefloe installed into it from the checkout (not editable), the robot's
config in ``/etc/icefloe/robots/<name>.toml``.

Everything the install adds to the machine (files, folders, the user, groups, boot lines,
enabled units) is written down in `MANIFEST` as it is added; ``remove`` undoes exactly that.
"""

from __future__ import annotations

import argparse
import contextlib
import grp
import hashlib
import json
import os
import pwd
import shlex
import shutil
import subprocess
import sys
import tempfile
import threading
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from packaging.tags import sys_tags

from . import config as config_mod
from . import credentials as credentials_mod
from . import lock, paths
from .config import RobotConfig
from .errors import ConfigError

SYSTEMD_TEMPLATES = paths.packaged("systemd")
UNIT_DIR = Path("/etc/systemd/system")
USER = "icefloe"
SERVICE_ENV = {"PYTHONUNBUFFERED": "1", "MALLOC_ARENA_MAX": "2", "OPENBLAS_NUM_THREADS": "1"}
"""The environment of icefloe's own processes, from systemd (``Environment=`` of each unit) and from
`icefloe up` alike. ``MALLOC_ARENA_MAX``: glibc gives each thread that allocates an arena of its
own, up to eight per core, and keeps what it grew: 4,000 camera queries, 32 at a time (worker
threads encoding frames), left the camera 8.4 MiB larger with glibc's default, 3.3 with two
(docs/hostile-input.md). ``OPENBLAS_NUM_THREADS``: NumPy's and OpenCV's BLAS start a thread per
core when imported, each with its buffers, for matrices of a few rows; with one, the fork server
(`icefloe.forkserver`) has no thread when it forks."""
USER_HOME = Path("/var/lib/icefloe")
GROUPS = ("dialout", "spi", "i2c", "gpio", "video")
PREFIX = Path("/opt/icefloe")
VENV = PREFIX / "venv"
PYTHON = VENV / "bin" / "python"
MANIFEST = PREFIX / "install.json"
ETC = paths.SYSTEM_DIR
ROBOTS = ETC / "robots"
UDEV_RULES_PATH = Path("/etc/udev/rules.d/99-icefloe.rules")
TMPFILES = Path("/etc/tmpfiles.d/icefloe.conf")
BOOT_CONFIG = Path("/boot/firmware/config.txt")
CMDLINE = BOOT_CONFIG.parent / "cmdline.txt"
BOOT_LINES = (
    "enable_uart=1",          # the PenguinPi's serial link on GPIO14/15
    "dtoverlay=disable-bt",   # ... on the full PL011 UART, not the mini-UART that follows the CPU clock
    "dtparam=spi=on",         # the icoBoard
    "dtparam=i2c_arm=on",     # the OLED and battery monitors
)
UDEV_RULES = """\
# icefloe: the robot's user reaches the board without root
KERNEL=="ttyAMA[0-9]*|serial[0-9]*", GROUP="dialout", MODE="0660"
SUBSYSTEM=="spidev", GROUP="spi", MODE="0660"
SUBSYSTEM=="i2c-dev", GROUP="i2c", MODE="0660"
SUBSYSTEM=="gpio", KERNEL=="gpiochip*", GROUP="gpio", MODE="0660"
"""
APT_ALWAYS = ("rt-tests", "gpiod", "i2c-tools", "python3-venv")
"""cyclictest (bench/hwbridge_latency.py), the GPIO and I2C tools, and what makes the venv."""
SOURCE_PARTS = ("pyproject.toml", "README.md", "icefloe", "schemas", "services", "sim", "deploy", "gateware")
"""What of a checkout goes into icefloe's wheel (pyproject.toml's package-dir): copied and hashed."""


# ---------------------------------------------------------------------- what the install added


class Manifest:
    """What an install added to this machine, as ``[kind, value, ...]`` entries in a JSON file.

    Kinds: ``tree`` (a folder of ours: removed whole), ``dir`` (removed if empty), ``file``,
    ``credentials`` (kept by ``remove`` unless ``--purge``), ``user``, ``group``, ``unit`` (enabled),
    ``line`` (path, a line added to it), ``cmdline+`` / ``cmdline-`` (path, a word added to /
    removed from the kernel command line), ``apt`` (installed, and left installed by ``remove``).
    Written after every addition, so that an install that stops half-way can still be removed.
    """

    def __init__(self, path: Path | None = MANIFEST, entries: list[list[str]] | None = None) -> None:
        self.path = path
        self.entries: list[list[str]] = entries if entries is not None else []

    @classmethod
    def load(cls, path: Path = MANIFEST) -> Manifest:
        try:
            entries = json.loads(path.read_text())["added"]
        except FileNotFoundError:
            entries = []
        except (ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"{path}: not an install manifest ({exc})") from None
        return cls(path, [list(map(str, e)) for e in entries])

    def add(self, kind: str, *values: object) -> None:
        entry = [kind, *map(str, values)]
        if entry not in self.entries:
            self.entries.append(entry)
            self.save()

    def of(self, kind: str) -> list[list[str]]:
        return [e[1:] for e in self.entries if e[0] == kind]

    def save(self) -> None:
        if self.path is None or not self.path.parent.is_dir():
            return  # before its folder exists (the first steps): saved by the next addition
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(json.dumps({"added": self.entries}, indent=1) + "\n")
        tmp.replace(self.path)


# ---------------------------------------------------------------------- steps


Step = Callable[[Manifest], bool]
"""A step in Python: does its work, records what it added, returns whether it changed anything."""


@dataclass(frozen=True)
class Action:
    what: str
    command: tuple[str, ...] = ()
    path: Path | None = None
    content: str = ""
    mode: int = 0o644
    ensure_lines: tuple[str, ...] = ()
    """With ``path``: append each of these lines unless the file already has it (the file is kept)."""
    step: Step | None = None
    detail: str = ""
    """What ``step`` does, for the dry run."""
    tolerant: str = ""
    """For a command: if it fails, print this one line and go on (e.g. no udevd in a container)."""
    on_change: Callable[[], None] | None = field(default=None, compare=False)
    """Called when doing it changed something (a new unit file: restart the units)."""
    when: Callable[[], bool] | None = field(default=None, compare=False)
    """Do it only if this says so when its turn comes (reload udev only if its rules changed)."""

    def describe(self) -> str:
        if self.step is not None:
            body = "".join(f"  {line}\n" for line in self.detail.splitlines())
            return f"* {self.what}\n{body}"
        if self.ensure_lines:
            body = "".join(f"    + {line}\n" for line in self.ensure_lines)
            return f"* {self.what}\n  ensure {self.path} has the lines:\n{body}"
        if self.path is not None:
            body = "".join(f"    | {line}\n" for line in self.content.splitlines())
            return f"* {self.what}\n  write {self.path} (mode {self.mode:o}):\n{body}"
        return f"* {self.what}\n  run: {shlex.join(self.command)}\n"

    def do(self, manifest: Manifest | None = None) -> bool:
        """Do it; True if it changed something."""
        changed = self._do(manifest if manifest is not None else Manifest(None))
        if changed and self.on_change is not None:
            self.on_change()
        return changed

    def _do(self, manifest: Manifest) -> bool:
        if self.when is not None and not self.when():
            return False
        if self.step is not None:
            return self.step(manifest)
        if self.ensure_lines:
            assert self.path is not None
            return ensure_lines(self.path, self.ensure_lines, manifest)
        if self.path is not None:
            changed = write_file(self.path, self.content, self.mode, manifest)
            print(f"  {'wrote' if changed else 'unchanged:'} {self.path}", flush=True)
            return changed
        try:
            run(*self.command)
        except (subprocess.CalledProcessError, FileNotFoundError):
            if not self.tolerant:
                raise
            print(f"  {self.tolerant}", flush=True)
            return False
        return True


def write_file(path: Path, content: str, mode: int, manifest: Manifest) -> bool:
    """Write ``path`` unless it holds ``content`` with ``mode`` already; a new file goes in the manifest."""
    if path.is_file() and path.read_text() == content and (path.stat().st_mode & 0o7777) == mode:
        return False
    make_dir(path.parent, manifest)
    new = not path.exists()
    path.write_text(content)
    os.chmod(path, mode)
    if new:
        manifest.add("file", path)
    return True


def make_dir(path: Path, manifest: Manifest, kind: str = "dir") -> bool:
    """Make ``path`` and its missing parents (mode 0755), each one in the manifest."""
    if path.is_dir():
        return False
    make_dir(path.parent, manifest)
    path.mkdir(mode=0o755)
    manifest.add(kind, path)
    return True


def ensure_lines(path: Path, lines: tuple[str, ...], manifest: Manifest) -> bool:
    have = path.read_text().splitlines() if path.exists() else []
    missing = [line for line in lines if line not in have]
    if not missing:
        return False
    with path.open("a") as f:
        f.writelines(line + "\n" for line in missing)
    for line in missing:
        manifest.add("line", path, line)
    return True


def edit_cmdline(path: Path, cpu: int, manifest: Manifest) -> bool:
    """The kernel command line (one line): no serial login console; ``isolcpus=<cpu>`` unless set."""
    words = path.read_text().split()
    removed = [w for w in words if w.startswith("console=serial0,")]
    kept = [w for w in words if w not in removed]
    added = [] if any(w.startswith("isolcpus=") for w in kept) else [f"isolcpus={cpu}"]
    if not removed and not added:
        return False
    path.write_text(" ".join(kept + added) + "\n")
    for word in removed:
        manifest.add("cmdline-", path, word)
    for word in added:
        manifest.add("cmdline+", path, word)
    return True


def run(*command: str | os.PathLike[str], quiet: bool = False, **kwargs: object) -> None:
    """Run a command, saying so; ``quiet``: its output only if it fails (apt's and pip's progress)."""
    print(f"  run: {shlex.join(map(str, command))}", flush=True)
    if not quiet:
        subprocess.run([os.fspath(c) for c in command], check=True, **kwargs)  # type: ignore[call-overload]
        return
    res = subprocess.run([os.fspath(c) for c in command], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                         text=True, **kwargs)  # type: ignore[call-overload]
    if res.returncode:
        print("".join(res.stdout.splitlines(keepends=True)[-30:]), end="", flush=True)
        raise subprocess.CalledProcessError(res.returncode, command)


def systemd_running() -> bool:
    """systemd is PID 1 here (sd_booted): units can be started now, not only enabled."""
    return Path("/run/systemd/system").is_dir()


# ---------------------------------------------------------------------- what a robot needs


def rt_cpu(config: RobotConfig) -> int:
    """The CPU hwbridge's cycle runs on (the last one unless the config says)."""
    return config.hwbridge.cpu if config.hwbridge.cpu >= 0 else (os.cpu_count() or 1) - 1


def apt_packages(config: RobotConfig) -> tuple[tuple[str, ...], dict[str, str]]:
    """The Debian packages of this robot: those every robot needs, and those its config asks for
    (package -> what needs it), installed where apt knows them (Raspberry Pi OS; plain Debian has
    no python3-picamera2)."""
    wanted: dict[str, str] = {}
    if "camera" in config.services and config.camera.source == "picamera2":
        why = 'the camera (camera.source = "picamera2")'
        wanted["python3-picamera2"] = why
        wanted["python3-libcamera"] = why
    b = config.board
    if "hwbridge" in config.services and b.kind == "icoboard" and b.backend == "hardware":
        wanted["python3-spidev"] = 'the icoBoard\'s SPI link (board.kind = "icoboard")'
    return APT_ALWAYS, wanted


def apt_known(package: str) -> bool:
    """apt has a candidate version of ``package`` (after ``apt-get update``)."""
    res = subprocess.run(["apt-cache", "policy", package], capture_output=True, text=True)
    return any(line.strip().startswith("Candidate:") and "(none)" not in line for line in res.stdout.splitlines())


def apt_installed(package: str) -> bool:
    res = subprocess.run(["dpkg-query", "-W", "-f=${Status}", package], capture_output=True, text=True)
    return res.returncode == 0 and res.stdout.endswith(" installed")


def install_apt(required: tuple[str, ...], wanted: dict[str, str], manifest: Manifest) -> bool:
    missing = [p for p in (*required, *wanted) if not apt_installed(p)]
    if not missing:
        return False
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    if any(p in required or apt_known(p) for p in missing):  # (a reinstall on plain Debian: no update)
        run("apt-get", "update", "-qq", env=env, quiet=True)
    install = [p for p in missing if p in required]
    for package in (p for p in missing if p in wanted):
        if apt_known(package):
            install.append(package)
        else:
            print(f"  {package}: apt does not know it here (not Raspberry Pi OS?): {wanted[package]} "
                  "will not start on this machine", flush=True)
    if install:
        run("apt-get", "install", "-y", "-qq", *install, env=env, quiet=True)
        for package in install:
            manifest.add("apt", package)
    return bool(install)


def checkout() -> Path | None:
    """The source tree this icefloe runs from (an editable install of a checkout), if it is one."""
    top = Path(__file__).resolve().parent.parent
    try:
        return top if 'name = "icefloe"' in (top / "pyproject.toml").read_text() else None
    except OSError:
        return None


def source_digest(source: str) -> str:
    """What identifies the icefloe a venv holds: the content of a checkout's files that go into the
    wheel, a wheel file's bytes, or a pip requirement's text. Equal digests: nothing to install."""
    h = hashlib.sha256()
    path = Path(source)
    if path.is_dir():
        for part in SOURCE_PARTS:
            top = path / part
            files = [top] if top.is_file() else sorted(p for p in top.rglob("*") if p.is_file())
            for f in files:
                if "__pycache__" in f.parts or f.suffix == ".pyc":
                    continue
                h.update(str(f.relative_to(path)).encode() + b"\0" + f.read_bytes() + b"\0")
    elif path.is_file():
        h.update(path.read_bytes())
    else:
        h.update(source.encode())
    return h.hexdigest()[:16]


def base_python() -> str:
    """The system's python3 (whose site packages apt fills), not the venv's this runs in."""
    return getattr(sys, "_base_executable", sys.executable)


def lock_of(source: str, into: Path) -> Path | None:
    """The folder of the lock's exports that belong to ``source``: a checkout's ``deploy/requirements``,
    a wheel's own (copied out into ``into``); None for a pip requirement, which carries no lock."""
    path = Path(source)
    if path.is_dir():
        return path / "deploy" / "requirements"
    if path.is_file() and path.suffix == ".whl":
        with zipfile.ZipFile(path) as wheel:
            names = [n for n in wheel.namelist() if n.startswith("icefloe/share/requirements/") and n.endswith(".txt")]
            if not names:
                raise ConfigError(f"{source}: this wheel carries no lock (icefloe/share/requirements/): "
                                  "build it again from a checkout with the lock")
            into.mkdir(parents=True, exist_ok=True)
            for name in names:
                (into / Path(name).name).write_bytes(wheel.read(name))
        return into
    return None


def lock_files(folder: Path, extras: str) -> list[Path]:
    """The exports to install for ``extras`` (``robot``, ``robot,icoboard``): pip and setuptools
    first (``build.txt``), then one file per extra (each holds the base too)."""
    names = [e.strip() for e in extras.split(",") if e.strip()] or ["base"]
    files = [folder / f"{n}.txt" for n in ["build", *names]]
    for f in files:
        if not f.exists():
            raise ConfigError(f"{f}: no such export of the lock: is {f.stem!r} an extra of icefloe?")
    return files


def check_wheelhouse(source: str, extras: str, wheelhouse: Path) -> None:
    """Refuse (`ConfigError`, one line) a wheelhouse that cannot install the lock of ``source`` on
    this machine: a package missing, or a file that is not one the lock lists."""
    with tempfile.TemporaryDirectory(prefix="icefloe-lock-") as tmp:
        folder = lock_of(source, Path(tmp))
        if folder is None:
            raise ConfigError(f"--wheelhouse: {source} is a pip requirement, which carries no lock to check "
                              "the wheelhouse against: give a wheel file or a checkout")
        locked = lock.pins([f.stem for f in lock_files(folder, extras)], directory=folder)
        # only wheels this machine can install: the lock lists every machine's files (an x86_64 laptop's
        # download would pass a hash check for a Pi, and pip would then fail half-way through the install)
        problems = lock.wheelhouse_problems(wheelhouse, locked, tags=set(sys_tags()))
    if problems:
        more = f" (and {len(problems) - 3} more)" if len(problems) > 3 else ""
        raise ConfigError(f"--wheelhouse {wheelhouse}: does not match the lock ({lock.this_machine()}): "
                          + "; ".join(problems[:3]) + more)


def install_venv(source: str, extras: str, manifest: Manifest, wheelhouse: str = "") -> bool:
    """`VENV` with icefloe[extras] from ``source`` (a checkout, a wheel, a requirement), once per source:
    every dependency at the lock's version, each file's hash checked (from ``wheelhouse`` only, if given)."""
    changed = make_dir(PREFIX, manifest, kind="tree")
    if not PYTHON.exists():
        run(base_python(), "-m", "venv", "--system-site-packages", VENV)
        changed = True
    stamp = VENV / f".icefloe-{extras}-{source_digest(source)}"
    if stamp.exists():
        print(f"  {VENV} holds this icefloe already ({stamp.name})", flush=True)
        return changed
    pip = [PYTHON, "-m", "pip", "install", "--no-warn-script-location"]
    if wheelhouse:
        pip += ["--no-index", "--find-links", wheelhouse]
    with tempfile.TemporaryDirectory(prefix="icefloe-install-") as tmp:
        target = source
        if Path(source).is_dir():
            # Build from a copy: a build in the checkout would leave root's files in someone's home.
            target = os.path.join(tmp, "icefloe")
            for part in SOURCE_PARTS:
                src = Path(source) / part
                if src.is_dir():
                    shutil.copytree(src, Path(target) / part,
                                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info"))
                elif src.is_file():
                    Path(target).mkdir(parents=True, exist_ok=True)
                    shutil.copy2(src, Path(target) / part)
        folder = lock_of(source, Path(tmp) / "lock")
        if folder is None:
            # a requirement (a name, a URL) is the caller's to write, extras and all
            print(f"  {source} is a pip requirement: it carries no lock, so pip takes the newest versions "
                  "within its ranges (icefloe doctor names what differs from the lock)", flush=True)
            run(*pip, "--upgrade", source, quiet=True)
        else:
            for requirements in lock_files(folder, extras):
                run(*pip, "--require-hashes", "-r", requirements, quiet=True)
            run(*pip, "--no-deps", "--no-build-isolation", "--force-reinstall", target, quiet=True)
    for old in VENV.glob(".icefloe-*"):
        old.unlink()
    stamp.touch()
    return True


def config_files(config_path: Path, name: str) -> dict[Path, Path]:
    """The files of a config's ``extends`` chain that the installed icefloe does not ship, and where
    each goes (``/etc/icefloe/robots/``: the config itself as ``<name>.toml``, the files it extends
    under their own names, so that ``extends`` finds them next to it)."""
    shipped = paths.packaged("robots").resolve()
    out = {config_path: ROBOTS / f"{name}.toml"}
    path, seen = config_path, {config_path}
    while True:
        parent = config_mod.read_toml(path).get("extends")
        if not isinstance(parent, str):
            return out
        base = path.parent / parent
        if base.resolve() == path or not base.exists():
            base = paths.find("robots", parent.removesuffix(".toml"), "robot config", skip=path)
        elif "/" in parent:
            raise ConfigError(f"{path}: extends = {parent!r}: a file in another folder cannot be installed "
                              f"beside it in {ROBOTS}; name a file in the same folder, or a shipped robot")
        base = base.resolve()
        if base.parent == shipped or base in seen:
            return out  # the installed icefloe ships it: `extends` finds it by name
        dest = ROBOTS / base.name
        if dest in out.values():
            raise ConfigError(f"{base}: two files of {config_path}'s `extends` chain would be {dest}")
        out[base] = dest
        seen.add(base)
        path = base


def units(config: RobotConfig, config_path: Path, python: str | os.PathLike[str]) -> dict[str, str]:
    """Unit file name -> content, from the templates in deploy/systemd/."""
    cpu = rt_cpu(config)
    values = {"robot": config.name, "user": USER, "python": str(python), "config": str(config_path),
              "cpu": str(cpu), "cpus": str(cpu), "socket": str(config.runtime_dir / "forkserver.sock"),
              "environment": " ".join(f"{key}={value}" for key, value in SERVICE_ENV.items())}
    out = {}
    for template in sorted(SYSTEMD_TEMPLATES.iterdir()):
        text = template.read_text()
        for key, value in values.items():
            text = text.replace("{" + key + "}", value)
        out[template.name] = text
    return out


def services_of(config: RobotConfig) -> list[str]:
    """The template-unit services this robot runs (hwbridge has its own unit; no simulator on a robot)."""
    return [s for s in config.services if s not in ("hwbridge", "sim")]


SLICE = "icefloe.slice"
"""Every unit's slice: the robot's services apart from the students' programs (docs/deploy.md)."""


def unit_names(config: RobotConfig) -> list[str]:
    return ["icefloe.target", "icefloe-forkserver.service", "icefloe-router.service", "icefloe-hwbridge.service",
            *(f"icefloe@{s}.service" for s in services_of(config))]


# ---------------------------------------------------------------------- the user and groups


def ensure_group(name: str, manifest: Manifest) -> bool:
    try:
        grp.getgrnam(name)
        return False
    except KeyError:
        run("groupadd", "--system", name)
        manifest.add("group", name)
        return True


def ensure_user(manifest: Manifest) -> bool:
    changed = False
    try:
        pwd.getpwnam(USER)
    except KeyError:
        run("useradd", "--system", "--home-dir", USER_HOME, "--create-home", "--shell", "/usr/sbin/nologin",
            "--user-group", USER)
        manifest.add("user", USER)
        changed = True
    missing = [g for g in GROUPS if USER not in grp.getgrnam(g).gr_mem]
    if missing:
        run("usermod", "-aG", ",".join(missing), USER)
        changed = True
    return changed


def ensure_credentials(config: RobotConfig, host: str, manifest: Manifest) -> bool:
    path = Path(config.zenoh.credentials)
    port = config.zenoh.listen[0].rsplit(":", 1)[-1] if config.zenoh.listen else "7447"
    made_dir = make_dir(path.parent, manifest)
    _, created = credentials_mod.make(path, config.name, [f"tcp/{host}:{port}"] if host else [])
    print(f"  {'made' if created else 'kept'} {path}", flush=True)
    manifest.add("credentials", path)  # made now or before: this install gives it to icefloe, remove takes it back
    st = path.stat()
    user = pwd.getpwnam(USER)
    if (st.st_uid, st.st_gid, st.st_mode & 0o7777) == (user.pw_uid, user.pw_gid, 0o600):
        return created or made_dir
    os.chown(path, user.pw_uid, user.pw_gid)
    os.chmod(path, 0o600)
    return True


def copy_file(src: Path, dest: Path, manifest: Manifest) -> bool:
    if src.resolve() == dest.resolve():
        print(f"  {dest} is the config this install was given", flush=True)
        return False  # the name resolved to /etc/icefloe/robots/: edited there, kept as it is
    changed = write_file(dest, src.read_text(), 0o644, manifest)
    print(f"  {'wrote' if changed else 'unchanged:'} {dest}", flush=True)
    return changed


def make_runtime_dir(path: Path, manifest: Manifest) -> bool:
    if path.is_dir():
        return False
    run("systemd-tmpfiles", "--create", TMPFILES)
    manifest.add("tree", path)  # ours: made by this install (removed with what the services left in it)
    return True


def check_as_user(config_path: Path) -> bool:
    """The services' user reads the config, the files it extends, and icefloe itself, as the units will."""
    run("runuser", "-u", USER, "--", PYTHON, "-m", "icefloe.cli", "config", config_path,
        stdout=subprocess.DEVNULL)
    return False


def enable_units(names: list[str], changed: bool, manifest: Manifest) -> bool:
    """Enable the units and start the robot; restart it when a unit or icefloe itself ``changed``.

    Started is judged by ``icefloe.target`` alone: a service that cannot start here (the camera
    without picamera2, exit 2) stays failed, and installing again must not count that as a change.
    """
    for name in names:
        manifest.add("unit", name)
    enabled = subprocess.run(["systemctl", "is-enabled", "--quiet", *names]).returncode == 0
    if not systemd_running():
        # An image or a container without systemd as PID 1: enable (links), start at the next boot.
        if not enabled:
            run("systemctl", "enable", *names)
        print("  systemd is not running here: the units start at the next boot", flush=True)
        return not enabled
    if changed:
        run("systemctl", "daemon-reload")
    if not enabled:
        run("systemctl", "enable", *names)
    active = subprocess.run(["systemctl", "is-active", "--quiet", "icefloe.target"]).returncode == 0
    if changed and active:
        run("systemctl", "restart", "icefloe.target")  # every unit is PartOf it: all of them restart
    elif not active:
        run("systemctl", "start", "icefloe.target")  # it wants every enabled unit
    return changed or not enabled or not active


# ---------------------------------------------------------------------- the plans


@dataclass
class Options:
    host: str = ""
    """The robot's address, written into its credentials file."""
    boot_config: bool = True
    """Edit /boot/firmware/config.txt and cmdline.txt (a Raspberry Pi's)."""
    source: str = ""
    """What to install into the venv: a checkout (default: the one running), a wheel, a requirement."""
    extras: str = "robot"
    wheelhouse: str = ""
    """A folder of wheels to install from, with nothing downloaded (``--wheelhouse``): checked against the lock."""


def install_plan(config: RobotConfig, config_path: Path, options: Options | None = None) -> list[Action]:
    o = options or Options()
    source = o.source or str(checkout() or "")  # "": main() refuses to install without one
    installed = ROBOTS / f"{config.name}.toml"
    copies = config_files(config_path, config.name)
    cpu = rt_cpu(config)
    required, wanted = apt_packages(config)
    want = "".join(f"\n  and, where apt knows it: {p} ({why})" for p, why in wanted.items())
    restart = threading.Event()  # a unit file or icefloe itself changed: (re)start the units
    udev = threading.Event()  # the rules changed: reload them
    plan = [
        Action("system packages: the real-time test tool, GPIO and I2C tools, venv"
               + (", and what the config needs" if wanted else ""),
               step=lambda m: install_apt(required, wanted, m),
               detail=f"apt-get install {' '.join(required)} (unless installed){want}"),
        Action(f"icefloe in its own venv, readable by {USER} (system site packages: apt's picamera2, spidev)",
               step=lambda m: install_venv(source, o.extras, m, o.wheelhouse), on_change=restart.set,
               detail=f"{base_python()} -m venv --system-site-packages {VENV}\n"
                      + (f"{PYTHON} -m pip install --require-hashes -r <the lock of {source}: build.txt, then "
                         f"{o.extras}.txt>" + (f" --no-index --find-links {o.wheelhouse}" if o.wheelhouse else "")
                         + f"\n{PYTHON} -m pip install --no-deps '{source}' (a copy; not editable)\n" if source else
                         "<--source: this icefloe is not a checkout>\n")
                      + f"skipped when {VENV}/.icefloe-{o.extras}-<digest of the source> exists"),
    ]
    plan += [Action(f"group {g}", step=lambda m, g=g: ensure_group(g, m),
                    detail=f"groupadd --system {g} (unless it exists)") for g in GROUPS]
    plan += [
        Action(f"a system user {USER!r} for the services (home {USER_HOME}), in the hardware groups",
               step=ensure_user,
               detail=f"useradd --system --home-dir {USER_HOME} --create-home --shell /usr/sbin/nologin "
                      f"--user-group {USER} (unless it exists)\nusermod -aG {','.join(GROUPS)} {USER}"),
    ]
    plan += [Action(f"the robot's config{' ' if src == config_path else ', the file it extends, '}{dest}",
                    step=lambda m, src=src, dest=dest: copy_file(src, dest, m), on_change=restart.set,
                    detail=f"copy {src} to {dest} (mode 644)") for src, dest in copies.items()]
    plan += [
        Action("device permissions for the serial port, SPI, I2C and GPIO",
               path=UDEV_RULES_PATH, content=UDEV_RULES, on_change=udev.set),
        Action("reload udev rules (if they changed)", ("udevadm", "control", "--reload-rules"), when=udev.is_set,
               tolerant="udev is not running here (a container?): the rules apply from the next boot"),
    ]
    if o.boot_config:
        plan += [
            Action("boot config: serial port, SPI and I2C on (takes effect after a reboot)",
                   path=BOOT_CONFIG, ensure_lines=BOOT_LINES),
            Action("free the serial port from the login console, and keep CPU "
                   f"{cpu} for hwbridge's cycle alone (take effect after a reboot)",
                   step=lambda m: edit_cmdline(CMDLINE, cpu, m),
                   detail=f"in {CMDLINE}: remove console=serial0,<baud>; add isolcpus={cpu} "
                          "(unless an isolcpus= is there)"),
        ]
    if config.run_dir:  # (without one, each service makes its own under /tmp, as on a laptop)
        plan += [
            Action(f"the runtime folder {config.runtime_dir} for the services' sockets, at every boot, "
                   f"private to {USER}",
                   path=TMPFILES, content=f"d {config.runtime_dir} 0700 {USER} {USER} -\n"),
            Action("create it now", step=lambda m: make_runtime_dir(config.runtime_dir, m),
                   detail=f"run: systemd-tmpfiles --create {TMPFILES} (unless {config.runtime_dir} exists)"),
        ]
    if config.zenoh.access_control and config.zenoh.credentials:
        plan.append(Action(f"this robot's credentials (made once, private to {USER}, never printed)",
                           step=lambda m: ensure_credentials(config, o.host, m),
                           detail=f"icefloe credentials: {config.zenoh.credentials} unless it exists; "
                                  f"owner {USER}, mode 0600"))
    plan.append(Action(f"check: {USER} reads the config and runs the installed icefloe",
                       step=lambda m: check_as_user(installed),
                       detail=f"runuser -u {USER} -- {PYTHON} -m icefloe.cli config {installed}"))
    plan += [Action(f"systemd unit {name}", path=UNIT_DIR / name, content=text, on_change=restart.set)
             for name, text in units(config, installed, PYTHON).items()]
    enable = unit_names(config)
    plan.append(Action(f"enable and start: {' '.join(enable)}",
                       step=lambda m: enable_units(enable, restart.is_set(), m),
                       detail=f"run: systemctl daemon-reload\nrun: systemctl enable {' '.join(enable)}\n"
                              "run: systemctl start icefloe.target (restart, when a unit or icefloe changed; "
                              "where systemd is not running, only enabled)"))
    return plan


def remove_plan(manifest: Manifest, purge: bool = False) -> list[Action]:
    """Undo what the manifest says an install added, last first; apt packages stay."""
    plan: list[Action] = []
    units_ = [u for (u,) in manifest.of("unit")]
    if units_:
        running = systemd_running()
        plan.append(Action(f"stop and disable: {' '.join(units_)}",
                           ("systemctl", "disable", *(("--now",) if running else ()), *units_),
                           tolerant="systemctl could not disable them (gone already?)"))
        if running:  # the units' slice (deploy/systemd/icefloe.slice) stays up, empty, until stopped
            plan.append(Action(f"stop {SLICE}", ("systemctl", "stop", SLICE),
                               tolerant=f"systemctl could not stop {SLICE} (gone already?)"))
    files = [Path(p) for (p,) in manifest.of("file")]
    plan += [Action(f"remove {p}", ("rm", "-f", str(p))) for p in files]
    if units_ and systemd_running():
        plan.append(Action("reload systemd", ("systemctl", "daemon-reload")))
        plan.append(Action("forget the units' failures (a camera that could not start)",
                           ("systemctl", "reset-failed", *units_), tolerant="(none had failed)"))
    if UDEV_RULES_PATH in files:
        plan.append(Action("reload udev rules", ("udevadm", "control", "--reload-rules"),
                           tolerant="udev is not running here (a container?)"))
    for path, line in manifest.of("line"):
        plan.append(Action(f"remove the line {line!r} from {path}",
                           step=lambda m, path=path, line=line: remove_line(Path(path), line),
                           detail=f"remove the line {line} from {path}"))
    for sign in ("cmdline+", "cmdline-"):
        for path, word in manifest.of(sign):
            verb = "remove" if sign == "cmdline+" else "put back"
            plan.append(Action(f"{verb} {word} in {path}",
                               step=lambda m, path=path, word=word, sign=sign: undo_cmdline(Path(path), word, sign),
                               detail=f"{verb} {word} in {path}"))
    for (path,) in manifest.of("credentials"):
        if purge:
            plan.append(Action(f"remove the robot's credentials {path} (--purge)", ("rm", "-f", path)))
        else:
            plan.append(Action(f"keep the robot's credentials {path} (its owners hold the same password; "
                               "--purge removes it), now root's", ("chown", "root:root", path),
                               tolerant=f"{path} is gone already"))
    for (user,) in manifest.of("user"):
        plan.append(Action(f"remove the user {user} and its home", ("userdel", "--remove", user),
                           tolerant=f"could not remove the user {user} (gone already?)"))
    for (group,) in manifest.of("group"):
        plan.append(Action(f"remove the group {group}", ("groupdel", group),
                           tolerant=f"could not remove the group {group} (gone already?)"))
    for (path,) in manifest.of("tree"):
        plan.append(Action(f"remove {path}" + (" (the venv, this manifest)" if Path(path) == PREFIX else ""),
                           ("rm", "-rf", path)))
    for (path,) in reversed(manifest.of("dir")):
        plan.append(Action(f"remove the folder {path} if empty", step=lambda m, path=path: remove_dir(Path(path)),
                           detail=f"rmdir {path} (if empty)"))
    return plan


def remove_line(path: Path, line: str) -> bool:
    with contextlib.suppress(FileNotFoundError):
        lines = path.read_text().splitlines(keepends=True)
        kept = [x for x in lines if x.rstrip("\n") != line]
        if kept != lines:
            path.write_text("".join(kept))
            return True
    return False


def undo_cmdline(path: Path, word: str, sign: str) -> bool:
    with contextlib.suppress(FileNotFoundError):
        words = path.read_text().split()
        if sign == "cmdline+" and word in words:
            words.remove(word)
        elif sign == "cmdline-" and word not in words:
            words.insert(0, word)
        else:
            return False
        path.write_text(" ".join(words) + "\n")
        return True
    return False


def remove_dir(path: Path) -> bool:
    try:
        path.rmdir()
        return True
    except OSError:
        return False  # gone, or holds something that is not ours (kept credentials, a TA's file)


# ---------------------------------------------------------------------- the command


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("action", choices=["install", "remove"], help="install the robot, or remove what an install added")
    p.add_argument("config", help="robot config file or name")
    p.add_argument("--dry-run", action="store_true", help="print every action, change nothing")
    p.add_argument("--host", default="", help="the robot's address, written into its credentials file")
    p.add_argument("--no-boot-config", action="store_true",
                   help="leave /boot/firmware/config.txt and cmdline.txt alone (not a Raspberry Pi, a container)")
    p.add_argument("--source", default="",
                   help="what to install into /opt/icefloe/venv: a checkout (default: this one), a wheel, "
                        "or a pip requirement")
    p.add_argument("--wheelhouse", default="", metavar="DIR",
                   help="install: every package from this folder of wheels, nothing downloaded (a lab without "
                        "internet); refused unless it holds the lock's file of each")
    p.add_argument("--purge", action="store_true", help="remove: the robot's credentials file too")
    args = p.parse_args(argv)
    try:
        cfg = config_mod.load(args.config)
        path = Path(cfg.source).resolve()
        if args.action == "install":
            if not args.no_boot_config and not args.dry_run and not BOOT_CONFIG.exists():
                raise ConfigError(f"{BOOT_CONFIG}: no such file (not a Raspberry Pi?): "
                                  "--no-boot-config installs without the boot config")
            if not args.dry_run and not (args.source or checkout()):
                raise ConfigError("this icefloe is not a checkout: say what to put into "
                                  f"{VENV} with --source (a wheel file, a pip requirement, a checkout)")
            if args.wheelhouse and (args.source or checkout()):
                args.wheelhouse = str(Path(args.wheelhouse).resolve())
                check_wheelhouse(args.source or str(checkout()), Options.extras, Path(args.wheelhouse))
            plan = install_plan(cfg, path, Options(args.host, not args.no_boot_config, args.source,
                                                   wheelhouse=args.wheelhouse))
            manifest = Manifest.load() if MANIFEST.exists() else Manifest()
        else:
            manifest = Manifest.load()
            plan = remove_plan(manifest, args.purge)
    except ConfigError as exc:
        print(f"icefloe {args.action}: {exc}", file=sys.stderr)
        return 78
    if not args.dry_run and os.geteuid() != 0:
        print(f"icefloe {args.action}: changes the system: run it as root (sudo)", file=sys.stderr)
        return 1
    verb = "would do" if args.dry_run else "doing"
    print(f"icefloe {args.action} for robot {cfg.name!r} ({path}): {verb} {len(plan)} steps")
    if args.action == "remove" and not plan:
        print(f"  {MANIFEST} lists nothing: no install to remove here")
    changed = 0
    for action in plan:
        # the dry run says what each step would do; a real one says what it does as it does it
        print(action.describe().rstrip("\n") if args.dry_run else f"* {action.what}", flush=True)
        if not args.dry_run:
            changed += action.do(manifest)
    if args.dry_run:
        print("\nDone (dry run: nothing changed).")
        return 0
    print(f"\nDone: {changed} steps changed something.")
    if args.action == "install":
        print("The robot runs as systemd units under icefloe.target: `journalctl -u 'icefloe*' -f` follows "
              "its logs." + ("" if args.no_boot_config else " Reboot once for the boot config to take effect."))
        if cfg.zenoh.access_control:
            print(f"Its credentials are in {cfg.zenoh.credentials}: give that file to whoever drives it.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
