"""Log lines about bad input, a few per second per kind: `LimitedLog`.

Every boundary of icefloe (a subscription, a queryable, an HTTP route, the board
link) can be flooded with bad input by a student's script gone wrong or on
purpose. Each bad input is dropped with a line naming what was wrong, but a
flood must not become a flood of lines (on stderr, and copied to the bus key
``log``)::

    limited = LimitedLog(node.log)
    limited.warning("cmd/twist", "dropped: icefloe/sim/cmd/twist: Expected `float`, got `str`")

At most ``burst`` lines of one *kind* are written per ``period``; the rest are
counted, and one more line says how many were not shown, once the period is
over. A kind is a short name chosen by the program (a key, a route), never text
from the input. Lines are cut to `MAX_TEXT` characters and control characters
are escaped, so input cannot forge or stretch log lines.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

MAX_TEXT = 300
"""Longest line written, characters (a payload's text can be quoted in an error message)."""
MAX_KINDS = 64
"""Kinds tracked at once; more are counted under ``"other"``."""


def printable(text: str, limit: int = MAX_TEXT) -> str:
    """``text`` cut to ``limit`` characters, control characters escaped (``\\n`` -> ``\\x0a``)."""
    if len(text) > limit:
        text = text[: limit - 1] + "…"
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else f"\\x{ord(c):02x}" for c in text)


@dataclass
class _Window:
    start: float
    written: int = 0
    held: int = 0
    level: int = logging.WARNING


class LimitedLog:
    """At most ``burst`` lines per kind per ``period`` s; the others are counted and reported.

    Safe to call from any thread (zenoh-python calls back on its own). The report of the lines
    held back comes at the end of the period (a timer on the event loop that built or first
    used this object, if there is one), or else with the next line of the kind, or `flush`.
    """

    def __init__(self, log: logging.Logger, *, burst: int = 3, period: float = 1.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.log, self.burst, self.period, self._clock = log, burst, period, clock
        self._windows: dict[str, _Window] = {}
        self._lock = threading.Lock()
        try:
            self._loop: asyncio.AbstractEventLoop | None = asyncio.get_running_loop()
        except RuntimeError:
            self._loop = None
        self.written = 0
        """Lines written so far (reports included)."""
        self.held = 0
        """Lines not written so far."""

    def warning(self, kind: str, text: str, *args: object) -> bool:
        return self.write(logging.WARNING, kind, text, *args)

    def info(self, kind: str, text: str, *args: object) -> bool:
        return self.write(logging.INFO, kind, text, *args)

    def error(self, kind: str, text: str, *args: object, exc_info: BaseException | None = None) -> bool:
        return self.write(logging.ERROR, kind, text, *args, exc_info=exc_info)

    def write(self, level: int, kind: str, text: str, *args: object,
              exc_info: BaseException | None = None) -> bool:
        """Write ``text % args`` at ``level`` unless ``kind`` had its ``burst`` this period;
        True if it was written. ``exc_info`` adds the traceback to the lines that are written."""
        now = self._clock()
        reports = []
        report_in: float | None = None
        with self._lock:
            window = self._windows.get(kind)
            if window is not None and now - window.start >= self.period:
                reports.append(self._close(kind))
                window = None
            if window is None:
                if len(self._windows) >= MAX_KINDS:  # forget the kinds whose period is over
                    reports += [self._close(k) for k, w in list(self._windows.items())
                                if now - w.start >= self.period]
                    if len(self._windows) >= MAX_KINDS:
                        kind = "other"
                window = self._windows.setdefault(kind, _Window(now))
            show = window.written < self.burst
            if show:
                window.written += 1
                self.written += 1
            else:
                window.held += 1
                window.level = max(window.level, level)
                self.held += 1
                if window.held == 1:
                    report_in = window.start + self.period - now
        for report in reports:
            if report:
                self._report(*report)
        if show:
            self.log.log(level, "%s", printable(text % args if args else text), exc_info=exc_info)
        elif report_in is not None:
            self._report_later(kind, report_in)
        return show

    def flush(self) -> None:
        """Report the lines held back so far (e.g. before exiting)."""
        with self._lock:
            reports = [self._close(kind) for kind in list(self._windows)]
        for report in reports:
            if report:
                self._report(*report)

    def _close(self, kind: str) -> tuple[str, int, int, float] | None:
        """End a kind's period (lock held); what to report, if lines were held back."""
        window = self._windows.pop(kind)
        if not window.held:
            return None
        return kind, window.held, window.level, self._clock() - window.start

    def _report(self, kind: str, held: int, level: int, seconds: float) -> None:
        self.written += 1
        self.log.log(level, "%s: %d more like it not shown (in %.1f s)", printable(kind), held, seconds)

    def _report_later(self, kind: str, delay: float) -> None:
        """Report ``kind``'s held lines when its period ends (on the event loop, if there is one)."""
        try:
            running: asyncio.AbstractEventLoop | None = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if self._loop is None:
            self._loop = running
        loop = self._loop
        if loop is None or loop.is_closed():
            return  # reported with the next line of this kind, or by flush()

        def due() -> None:
            with self._lock:
                window = self._windows.get(kind)
                report = self._close(kind) if window and self._clock() - window.start >= self.period else None
            if report:
                self._report(*report)

        try:
            if running is loop:
                loop.call_later(max(delay, 0.0) + 0.01, due)
            else:  # a Zenoh thread
                loop.call_soon_threadsafe(loop.call_later, max(delay, 0.0) + 0.01, due)
        except RuntimeError:  # the loop is closing
            pass
