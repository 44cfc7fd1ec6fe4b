"""The native Rerun viewer on this machine: where it is, whether it can open a window, starting it.

`rr.spawn()` looks for ``rerun`` on PATH, which holds the venv's ``bin/`` only when the venv is
activated; and without a display it waits 10 s, lets the viewer die, and logs into the void. So
viz starts the viewer itself: the ``rerun`` installed with *this* Python (``sysconfig``'s scripts
folder, e.g. ``.venv/bin/rerun``), only where a window can open, and keeps its process to notice
when the student closes the window.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import socket
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

from icefloe.errors import ConfigError

START_TIMEOUT_S = 30.0
"""How long the viewer may take to listen (software rendering on a busy machine is slow), s."""
SETTLE_S = 1.0
"""A viewer still running this long after it listens has its window open, s."""


def executable() -> str:
    """The ``rerun`` viewer installed with this Python, whatever PATH says; else the one on PATH.

    On Linux and Windows, the viewer binary itself (in the ``rerun_cli`` package), not the
    ``bin/rerun`` script that starts it: a signal to the process we start then reaches the viewer.
    """
    name = "rerun.exe" if sys.platform == "win32" else "rerun"
    if sys.platform != "darwin":  # (on macOS the script picks the app bundle: keep it)
        with contextlib.suppress(ImportError):
            import rerun_cli

            binary = Path(rerun_cli.__file__).parent / name
            if binary.exists():
                return str(binary)
    beside = Path(sysconfig.get_path("scripts")) / name
    found = str(beside) if beside.exists() else shutil.which("rerun")
    if not found:
        raise ConfigError(f"no Rerun viewer at {beside} nor on PATH: pip install 'icefloe[viz]' into this Python")
    return found


def display_problem() -> str | None:
    """Why no window can open here (one line), or None if one can."""
    if sys.platform in ("darwin", "win32") or os.environ.get("WAYLAND_DISPLAY") or os.environ.get("DISPLAY"):
        return None
    return "no display here (neither DISPLAY nor WAYLAND_DISPLAY is set)"


def how_to_look(robot_address: str = "<this-machine>") -> str:
    """One line: how to see the robot from where there is no display."""
    return (f"to see the robot: `icefloe viz --serve` here and open http://localhost:9090 in a browser, or run "
            f"`icefloe viz --connect tcp/{robot_address}:7447` on a machine with a screen")


def listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex(("127.0.0.1", port)) == 0


def _last_error(log: Path) -> str:
    """The viewer's own reason for exiting, without colours or paths into Rust sources."""
    try:
        lines = log.read_text(errors="replace").splitlines()
    except OSError:
        return "no output"
    lines = [re.sub(r"\x1b\[[0-9;]*m", "", line).strip() for line in lines]
    errors = [line for line in lines if "error" in line.lower()] or lines or ["no output"]
    return re.sub(r" at /\S+\.rs:\d+(:\d+)?", "", errors[-1])


class Viewer:
    """A native viewer listening on ``port``: the one already there, or one we start now.

    ``process`` is None when a viewer was already listening (a student's, or one left open by
    an earlier run): we stream to it and leave it be.
    """

    def __init__(self, port: int, memory_limit: str, log: Path) -> None:
        self.port = port
        self.url = f"rerun+http://127.0.0.1:{port}/proxy"
        self.process: subprocess.Popen[bytes] | None = None
        if listening(port):
            return
        if problem := display_problem():
            raise ConfigError(f"cannot open the Rerun viewer: {problem}; {how_to_look()}")
        log.parent.mkdir(parents=True, exist_ok=True)
        with open(log, "wb") as out:
            # Its own session: a Ctrl-C meant for the robot leaves the window and its data open.
            self.process = subprocess.Popen(
                [executable(), "--port", str(port), "--memory-limit", memory_limit, "--expect-data-soon",
                 "--hide-welcome-screen"],
                stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
                env={**os.environ, "RERUN_APP_ONLY": "true"})
        deadline = time.monotonic() + START_TIMEOUT_S
        up_since: float | None = None
        # It listens before it opens its window: it has started once it is still there a moment later.
        while up_since is None or time.monotonic() - up_since < SETTLE_S:
            if self.process.poll() is not None:
                raise ConfigError(f"the Rerun viewer exited at start ({_last_error(log)}); {how_to_look()}")
            if time.monotonic() > deadline:
                self.process.kill()
                raise ConfigError(f"the Rerun viewer did not listen on port {port} within {START_TIMEOUT_S:.0f} s "
                                  f"(its log: {log})")
            if up_since is None and listening(port):
                up_since = time.monotonic()
            time.sleep(0.1)

    def closed(self) -> bool:
        """Has the viewer we started exited (the window was closed)?"""
        return self.process is not None and self.process.poll() is not None
