"""Reading a camera on a thread of its own, the newest frame winning: the camera service's and the
lab's overhead localizer's capture loop.

`Capture` runs a thread that opens the source, reads frames into a one-frame slot
(`LatestFrame`) and, when the source fails, logs it, closes it and opens it again after
`RETRY_S`: a camera that fails never takes the service with it. A bad frame (`BadFrame`) is
skipped with a rate-limited line. The event loop takes the frames with ``async for frame in
capture.frames(...)``: when it falls behind, the frames it never saw are dropped and counted,
never queued.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections.abc import AsyncIterator, Callable

from ..logs import LimitedLog
from .sources import BadFrame, Frame, Source, check_frame

RETRY_S = 2.0
"""A camera that failed is opened again after this long, s."""
REPORT_S = 10.0
"""How often the frames dropped so far are reported (if any were), s."""
TAKE_S = 0.5
"""How long `Capture.frames` waits for a frame in one go (then looks again), s."""


class LatestFrame:
    """A one-frame slot between the capture thread and its reader; counts what was overwritten."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self.latest: Frame | None = None
        """The newest frame, kept for snapshots."""
        self.captured = 0
        self.dropped = 0

    def put(self, frame: Frame) -> None:
        with self._cond:
            if self._frame is not None:
                self.dropped += 1
            self._frame = self.latest = frame
            self.captured += 1
            self._cond.notify()

    def take(self, timeout: float) -> Frame | None:
        """The frame not taken yet, waiting at most ``timeout`` s for one; None if none came."""
        with self._cond:
            if self._frame is None:
                self._cond.wait(timeout)
            frame, self._frame = self._frame, None
            return frame


class Capture:
    """A camera read on its own thread (see the module's docstring).

    ``name`` says which camera in the log ("camera", "overhead camera"), ``spec`` its setting's
    value; ``open_source()`` opens it (`SourceError` if it cannot now); frames must be ``width`` x
    ``height``. ``on_frame(frame)``, if given, runs on the capture thread with each good frame, at
    once (the camera streams ``camera/frames`` from there)."""

    def __init__(self, name: str, spec: str, open_source: Callable[[], Source], width: int, height: int, *,
                 log: logging.Logger, limited: LimitedLog, thread_name: str,
                 on_frame: Callable[[Frame], object] | None = None, retry_s: float = RETRY_S) -> None:
        self.name, self.spec = name, spec
        self.slot = LatestFrame()
        self.source: Source | None = None
        """The open source (None while none is): the service may talk to it (the simulated one's truth)."""
        self.taken = 0
        """Frames `frames` has handed over."""
        self._open, self._width, self._height = open_source, width, height
        self._log, self._limited = log, limited
        self._on_frame, self._retry_s = on_frame, retry_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=thread_name, daemon=True)

    def start(self) -> None:
        self._thread.start()

    async def close(self) -> None:
        """Stop the thread (it closes the source) and wait for it a little longer than one retry."""
        self._stop.set()
        await asyncio.to_thread(self._thread.join, self._retry_s + 1.0)

    def _run(self) -> None:
        source: Source | None = None
        while not self._stop.is_set():
            try:
                if source is None:
                    source = self.source = self._open()
                    self._log.info("%s %r open", self.name, self.spec)
                stamp, image = source.read()
                frame = (stamp, check_frame(image, self._width, self._height))
                self.slot.put(frame)
                if self._on_frame is not None:
                    self._on_frame(frame)
            except BadFrame as exc:
                self._limited.warning("bad frame", "%s %r: bad frame skipped (%s)", self.name, self.spec, exc)
            except Exception as exc:  # a camera that fails must not take the service with it
                self._log.warning("%s %r failed: %s; retrying in %.0f s", self.name, self.spec, exc, self._retry_s)
                if source is not None:
                    with contextlib.suppress(Exception):
                        source.close()
                source = self.source = None
                self._stop.wait(self._retry_s)
        if source is not None:
            source.close()

    async def frames(self, report: str, clock: Callable[[], float] = time.monotonic) -> AsyncIterator[Frame]:
        """Each frame, the newest when the caller asks (waited for on a worker thread: the loop runs
        meanwhile). Every `REPORT_S`, if frames were dropped, ``report`` is logged with the frames
        captured, taken and dropped so far (three ``%d``)."""
        next_report = clock()
        while True:
            frame = await asyncio.to_thread(self.slot.take, TAKE_S)
            now = clock()
            if now >= next_report:
                if self.slot.dropped:
                    self._log.info(report, self.slot.captured, self.taken, self.slot.dropped)
                next_report = now + REPORT_S
            if frame is not None:
                self.taken += 1
                yield frame
