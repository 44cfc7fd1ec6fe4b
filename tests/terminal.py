"""A program in a pseudo-terminal, as a student runs it: keys in, what the screen shows out.

    term = Terminal([".venv/bin/icefloe", "teleop"])
    term.wait_for("driving")
    term.send("w")
    term.ctrl_c()                      # the terminal's Ctrl-C: SIGINT to the foreground program
    assert term.wait(10) == 0

The output is read all the time by a thread (a program that prints while nobody reads would
block on a full terminal), and kept for `wait_for` and `text`.
"""

from __future__ import annotations

import os
import re
import signal
import threading
import time
from pathlib import Path

from ptyprocess import PtyProcess

ANSI = re.compile(rb"\x1b\[[0-9;?]*[A-Za-z]")


class Terminal:
    def __init__(self, argv: list[str], *, cwd: Path | str | None = None, env: dict[str, str] | None = None,
                 size: tuple[int, int] = (40, 160)) -> None:
        self.argv = argv
        self.proc = PtyProcess.spawn(argv, cwd=str(cwd) if cwd else None, env=env, dimensions=size)
        self._out = bytearray()
        self._lock = threading.Lock()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        while True:
            try:
                data = self.proc.read(4096)
            except EOFError:
                return
            with self._lock:
                self._out += data

    @property
    def raw(self) -> bytes:
        with self._lock:
            return bytes(self._out)

    @property
    def text(self) -> str:
        """Everything printed so far, without colours and cursor movements."""
        return ANSI.sub(b"", self.raw).decode(errors="replace").replace("\r\n", "\n")

    def send(self, keys: str | bytes) -> None:
        self.proc.write(keys.encode() if isinstance(keys, str) else keys)

    def ctrl_c(self) -> None:
        """Ctrl-C typed at the terminal (the line discipline turns it into SIGINT)."""
        self.proc.sendintr()

    def wait_for(self, text: str, timeout: float = 20.0) -> None:
        deadline = time.monotonic() + timeout
        while text not in self.text:
            if time.monotonic() > deadline:
                raise AssertionError(f"{text!r} not shown within {timeout} s by {self.argv}:\n{self.text[-3000:]}")
            if not self.proc.isalive() and not self._reader.is_alive():
                raise AssertionError(f"{self.argv} ended without showing {text!r}:\n{self.text[-3000:]}")
            time.sleep(0.05)

    def alive(self) -> bool:
        return self.proc.isalive()

    def wait(self, timeout: float = 20.0) -> int:
        """The exit status (negative: the signal that ended it); kills it and fails after ``timeout``."""
        deadline = time.monotonic() + timeout
        while self.proc.isalive():
            if time.monotonic() > deadline:
                self.kill()
                raise AssertionError(f"{self.argv} still running {timeout} s later:\n{self.text[-3000:]}")
            time.sleep(0.05)
        self._reader.join(2.0)
        if self.proc.signalstatus is not None:
            return -self.proc.signalstatus
        return self.proc.exitstatus if self.proc.exitstatus is not None else -1

    def kill(self) -> None:
        if self.proc.isalive():
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()
