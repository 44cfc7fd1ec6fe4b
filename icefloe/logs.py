"""Log lines about bad input, a few per second: `LimitedLog`.

Every boundary of icefloe (a subscription, a queryable, an HTTP route, the board
link) can be flooded with bad input by a student's script gone wrong or on
purpose. Each bad input is dropped with a line naming what was wrong, but a
flood must not become a flood of lines (on stderr, and copied to the bus key
``log``)::

    limited = LimitedLog(node.log)
    limited.warning("cmd/twist", "dropped: %s", exc)

In each ``period`` (1 s) at most ``burst`` lines of one *kind* are written, and
at most ``limit`` lines in all; the others are counted, and one line at the end
of the period says how many of each kind were not shown. A kind is a short name
chosen by the program (a key, a route), never text from the input. Lines are
cut to `MAX_TEXT` characters and their control characters escaped, so input
can neither forge nor stretch log lines.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable

MAX_TEXT = 300
"""Longest line written, characters (an error message can quote a payload's text)."""
MAX_KINDS = 64
"""Kinds counted in one period; more are counted as ``"other"``."""


def printable(text: str, limit: int = MAX_TEXT) -> str:
    """``text`` cut to ``limit`` characters, control characters escaped (``\\n`` -> ``\\x0a``)."""
    if len(text) > limit:
        text = text[: limit - 1] + "…"
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else f"\\x{ord(c):02x}" for c in text)


class LimitedLog:
    """At most ``burst`` lines per kind and ``limit`` in all per ``period`` s; the rest are counted
    and reported in one line when the period is over.

    Safe to call from any thread (zenoh-python calls back on its own). The report comes from a
    timer on the event loop that built or first used this object; without a loop, with the next
    line, or from `flush`.
    """

    def __init__(self, log: logging.Logger, *, burst: int = 3, limit: int = 6, period: float = 1.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.log, self.burst, self.limit, self.period, self._clock = log, burst, limit, period, clock
        self._lock = threading.Lock()
        self._start: float | None = None
        """When the period under way began (None: no line since the last one ended)."""
        self._shown: Counter[str] = Counter()
        self._held: Counter[str] = Counter()
        self._held_level = logging.DEBUG
        try:
            self._loop: asyncio.AbstractEventLoop | None = asyncio.get_running_loop()
        except RuntimeError:
            self._loop = None
        self.written = 0
        """Lines written so far (reports included)."""
        self.held = 0
        """Lines not written so far."""

    def warning(self, kind: str, text: str, *args: object, exc_info: BaseException | None = None) -> bool:
        return self.write(logging.WARNING, kind, text, *args, exc_info=exc_info)

    def info(self, kind: str, text: str, *args: object, exc_info: BaseException | None = None) -> bool:
        return self.write(logging.INFO, kind, text, *args, exc_info=exc_info)

    def error(self, kind: str, text: str, *args: object, exc_info: BaseException | None = None) -> bool:
        return self.write(logging.ERROR, kind, text, *args, exc_info=exc_info)

    def write(self, level: int, kind: str, text: str, *args: object,
              exc_info: BaseException | None = None) -> bool:
        """Write ``text % args`` at ``level`` unless this period had its lines of ``kind`` (or in
        all) already; True if it was written. ``exc_info``: a traceback for the lines written."""
        now = self._clock()
        with self._lock:
            report = self._end_period(now) if self._start is not None and now - self._start >= self.period \
                else None
            if self._start is None:
                self._start = now
            if kind not in self._shown and kind not in self._held and \
                    len(self._shown) + len(self._held) >= MAX_KINDS:
                kind = "other"
            show = self._shown[kind] < self.burst and self._shown.total() < self.limit
            if show:
                self._shown[kind] += 1
                self.written += 1
            else:
                self._held[kind] += 1
                self._held_level = max(self._held_level, level)
                self.held += 1
            first_held = not show and self._held.total() == 1
            due = self._start + self.period - now
        if report:
            self._report(*report)
        if show:
            self.log.log(level, "%s", printable(text % args if args else text), exc_info=exc_info)
        elif first_held:
            self._report_later(due)
        return show

    def flush(self) -> None:
        """End the period now: report the lines held back so far (e.g. before exiting)."""
        with self._lock:
            report = self._end_period(self._clock())
        if report:
            self._report(*report)

    def _end_period(self, now: float) -> tuple[Counter[str], int, float] | None:
        """Close the period under way (lock held); what to report, if lines were held back."""
        seconds = 0.0 if self._start is None else now - self._start
        held, level = self._held, self._held_level
        self._start, self._shown, self._held, self._held_level = None, Counter(), Counter(), logging.DEBUG
        if not held:
            return None
        self.written += 1
        return held, level, seconds

    def _report(self, held: Counter[str], level: int, seconds: float) -> None:
        n = held.total()
        kinds = ", ".join(f"{count} {kind}" for kind, count in held.most_common())
        self.log.log(level, "%s", printable(f"{n} more line{'s' if n > 1 else ''} like these not shown in "
                                            f"{seconds:.1f} s: {kinds}"))

    def _report_later(self, delay: float) -> None:
        """Report when the period ends (on the event loop, if there is one)."""
        try:
            running: asyncio.AbstractEventLoop | None = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if self._loop is None:
            self._loop = running
        loop = self._loop
        if loop is None or loop.is_closed():
            return  # reported with the next line, or by flush()

        def due() -> None:
            with self._lock:
                if self._start is None:
                    return  # a line has ended the period (and reported) already
                left = self._start + self.period - self._clock()
                report = self._end_period(self._clock()) if left <= 0 else None
            if report:
                self._report(*report)
            elif left > 0:  # the loop's clock ran ahead of ours
                loop.call_later(left + 0.01, due)

        try:
            if running is loop:
                loop.call_later(max(delay, 0.0) + 0.01, due)
            else:  # a Zenoh thread
                loop.call_soon_threadsafe(loop.call_later, max(delay, 0.0) + 0.01, due)
        except RuntimeError:  # the loop is closing
            pass
