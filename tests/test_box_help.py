"""deploy/box.sh before it boots anything (docs/box.md): ``--help`` lists the commands as any user
and changes nothing, and what it runs as root leaves no file of root's in the user's checkout.

Each test runs box.sh in a copy of the files it reads, owned by ``nobody`` (a user who could write
there), so "changed nothing" means something. Needs root (``runuser``); skipped otherwise.
"""

from __future__ import annotations

import os
import pwd
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import ROOT

pytestmark = pytest.mark.skipif(
    os.geteuid() != 0 or not shutil.which("runuser") or not Path("/usr/bin/python3").exists(),
    reason="runs box.sh as another user: needs root, runuser and the system's python3")

COMMANDS = ("up", "build", "install", "exec", "board", "reboot", "down")

FAKE_SETUP = """\
# A stand-in for deploy/setup.sh: installs nothing, and says who made the .venv.
ensure_apt() { echo "ensure_apt $*" >> "$BOX_TEST_LOG"; }
ensure_venv() {
    mkdir -p .venv/bin
    ln -sf "$BOX_TEST_PYTHON" .venv/bin/python
    touch ".venv/made-by-$(id -un)"
}
"""
FAKE_BOX = """\
import os, sys
import boxhelper  # a module beside it: Python would write its bytecode into deploy/box/__pycache__
print("box.py ran as", os.geteuid(), sys.argv[1:])
"""


@pytest.fixture
def checkout() -> Iterator[Path]:
    """A folder owned by nobody, with box.sh and the files it reads (box.sh and box.py the real ones)."""
    folder = Path(tempfile.mkdtemp(prefix="icefloe-box-help-"))
    try:
        (folder / "deploy" / "box").mkdir(parents=True)
        shutil.copy2(ROOT / "deploy" / "box.sh", folder / "deploy" / "box.sh")
        shutil.copy2(ROOT / "deploy" / "setup.sh", folder / "deploy" / "setup.sh")
        shutil.copy2(ROOT / "deploy" / "box" / "box.py", folder / "deploy" / "box" / "box.py")
        folder.chmod(0o755)
        nobody = pwd.getpwnam("nobody")
        for path in [folder, *folder.rglob("*")]:
            os.chown(path, nobody.pw_uid, nobody.pw_gid)
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def tree(folder: Path) -> dict[str, tuple[int, int]]:
    """Every file and folder below ``folder``: (owner, mtime ns)."""
    return {str(p.relative_to(folder)): (p.lstat().st_uid, p.lstat().st_mtime_ns) for p in folder.rglob("*")}


def box(folder: Path, *args: str, user: str | None = None, env: dict[str, str] | None = None,
        ) -> subprocess.CompletedProcess[str]:
    """``deploy/box.sh ARGS`` in ``folder``: as root, or as ``user`` with a plain user's PATH (and so the
    system's python3, as a user who has no checkout's .venv)."""
    command = ["bash", "deploy/box.sh", *args]
    environment = {**os.environ, **(env or {})}
    if user:
        command = [shutil.which("runuser") or "runuser", "-u", user, "--", *command]
        environment = {**environment, "PATH": "/usr/local/bin:/usr/bin:/bin"}
        environment.pop("PYTHON", None)
    return subprocess.run(command, cwd=folder, capture_output=True, text=True, timeout=60, env=environment)


@pytest.mark.parametrize("user", ["nobody", None])
def test_help_lists_the_commands_as_any_user_and_changes_nothing(checkout: Path, user: str | None) -> None:
    before = tree(checkout)
    done = box(checkout, "--help", user=user)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: deploy/box.sh"), done.stdout
    for command in COMMANDS:
        assert command in done.stdout, (command, done.stdout)
    assert "run as root" not in done.stderr
    assert tree(checkout) == before, "box.sh --help created or changed files"


def test_a_help_after_dashdash_is_the_boxs_command_not_box_sh_s(checkout: Path) -> None:
    done = box(checkout, "exec", "--", "ls", "--help", user="nobody")
    assert done.returncode == 1 and "box: run as root" in done.stderr, done.stderr


def test_as_root_the_venv_is_the_checkouts_owner_and_no_file_is_roots(checkout: Path, tmp_path: Path) -> None:
    """box.sh with stand-ins for setup.sh and box.py: what it makes in the checkout is nobody's."""
    (checkout / "deploy" / "setup.sh").write_text(FAKE_SETUP)
    (checkout / "deploy" / "box" / "box.py").write_text(FAKE_BOX)
    (checkout / "deploy" / "box" / "boxhelper.py").write_text("")
    nobody = pwd.getpwnam("nobody")
    for name in ("setup.sh", "box/box.py", "box/boxhelper.py"):
        os.chown(checkout / "deploy" / name, nobody.pw_uid, nobody.pw_gid)
    log = tmp_path / "apt.log"
    done = box(checkout, "down", env={"BOX_TEST_LOG": str(log), "BOX_TEST_PYTHON": sys.executable})
    assert done.returncode == 0, done.stderr
    assert "box.py ran as 0 ['down']" in done.stdout  # box.py itself runs as root
    assert (checkout / ".venv" / "made-by-nobody").exists(), sorted(tree(checkout))
    roots = [path for path, (uid, _) in tree(checkout).items() if uid != nobody.pw_uid]
    assert not roots, f"root left these in the checkout: {roots}"
