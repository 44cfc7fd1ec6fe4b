"""Samples from the bus to many HTTP clients, with bounded memory: the HTTP bridge's plumbing.

One `Channel` per key expression holds one Zenoh subscriber, however many HTTP clients
read it: 100 browsers on ``odom/pose`` cost the robot one subscriber, and each sample is
turned into JSON once. Every client has its own bounded queue (`Reader`): a slow client
loses its oldest samples (and is told how many), never slows the others, never grows the
service's memory, and never reaches back to Zenoh (whose callback only appends to a
bounded deque and returns). A `Hub` keeps the channels, shares them, closes the unused.

    hub = Hub(session, render)                 # render(raw) -> JSON bytes of a sample, or None
    channel = hub.channel("icefloe/sim/**")    # shared; `hub.release(channel)` when done
    reader = channel.reader(rate=10.0)         # at most 10 samples a second per key, the newest
    async for batch in reader: ...             # lists of rendered samples, oldest first
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections import OrderedDict, deque
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass

import zenoh

from icefloe.logs import LimitedLog, printable
from icefloe.runtime import LoopWakeup
from icefloe.schemas import keys

log = logging.getLogger("icefloe.webapi")

CHANNEL_BACKLOG = 1024
"""Samples a channel holds between Zenoh's thread and the event loop (the oldest go first)."""
READER_EVENTS = 256
"""Samples one reader may have waiting (FIFO readers); the oldest go first."""
READER_BYTES = 256 * 1024
"""Bytes one reader may have waiting; the oldest samples go first."""
MAX_CHANNELS = 128
"""Key expressions followed at once; more is refused (503)."""
IDLE_S = 60.0
"""A channel nobody reads (no stream, no GET of its latest sample) is closed after this, s."""


def stamp_text(timestamp: zenoh.Timestamp | None) -> str:
    """A Zenoh timestamp as Zenoh's REST plugin writes it (``2026-11-24T04:29:15.18Z/<zid>``), or "None"."""
    if timestamp is None:
        return "None"
    return f"{timestamp.to_string_rfc3339_lossy()}/{timestamp.get_id()}"


@dataclass(frozen=True)
class Raw:
    """A sample or liveliness change as it came off the bus."""

    key: str
    payload: bytes
    encoding: str
    time: str
    """The sample's Zenoh timestamp (``"None"`` without one), as Zenoh's REST plugin shows it."""
    kind: str
    """``PUT`` or ``DELETE`` (a liveliness token that went away)."""


@dataclass(frozen=True)
class Rendered:
    """A sample ready for HTTP: its key and its JSON (``{"key", "value", "encoding", "time"}``)."""

    key: str
    kind: str
    json: bytes


Render = Callable[[Raw], Rendered | None]


class Reader:
    """One HTTP client's bounded queue on a channel; an async iterator of batches.

    FIFO (``rate`` None): every sample in order, at most `READER_EVENTS` / `READER_BYTES`
    waiting; when full the oldest go (counted in ``dropped``). With ``rate``: per key, at
    most ``rate`` samples a second, the newest (a sample replaces the one of its key that
    waits), so a state stream costs the client what it can show.
    """

    def __init__(self, channel: Channel, rate: float | None) -> None:
        self.channel = channel
        self.rate = rate
        self.dropped = 0
        """Samples this reader lost because its client was slow (not those a rate replaced)."""
        self._fifo: deque[Rendered] = deque()
        self._bytes = 0
        self._waiting: OrderedDict[str, Rendered] = OrderedDict()
        self._sent_at: dict[str, float] = {}
        self._wake = asyncio.Event()
        self.closed = False

    def offer(self, sample: Rendered) -> None:
        """Queue a sample (called in the loop by the channel's pump)."""
        if self.rate is not None:
            self._waiting[sample.key] = sample  # a newer sample of a key replaces the waiting one
            if len(self._waiting) > READER_EVENTS:  # a wildcard over very many keys
                self._waiting.popitem(last=False)
                self.dropped += 1
        else:
            self._fifo.append(sample)
            self._bytes += len(sample.json)
            while len(self._fifo) > READER_EVENTS or (self._bytes > READER_BYTES and len(self._fifo) > 1):
                self._bytes -= len(self._fifo.popleft().json)
                self.dropped += 1
        self._wake.set()

    def __aiter__(self) -> AsyncIterator[list[Rendered]]:
        return self._batches()

    async def _batches(self) -> AsyncIterator[list[Rendered]]:
        loop = asyncio.get_running_loop()
        while not self.closed:
            await self._wake.wait()
            self._wake.clear()
            if self.rate is None:
                batch, self._fifo, self._bytes = list(self._fifo), deque(), 0
                if batch:
                    yield batch
                continue
            while self._waiting and not self.closed:
                now = loop.time()
                period = 1.0 / self.rate
                due = [k for k in self._waiting if now - self._sent_at.get(k, -period) >= period]
                if due:
                    for k in due:
                        self._sent_at[k] = now
                    yield [self._waiting.pop(k) for k in due]
                    continue
                wait = min(self._sent_at[k] + period for k in self._waiting) - now
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), max(wait, 0.001))
                self._wake.clear()

    def close(self) -> None:
        self.closed = True
        self._wake.set()


class Channel:
    """One key expression followed on the bus, shared by every reader of it.

    ``liveliness``: follow the liveliness tokens under the expression too (``alive/<service>``
    appearing is a PUT, going away a DELETE), with the tokens alive now first. ``history``:
    keep the last samples, and give them to each new reader first (the log's last lines).
    """

    def __init__(self, session: zenoh.Session, key_expr: str, render: Render, *,
                 samples: bool = True, liveliness: bool = False, history: int = 0) -> None:
        self.key_expr = key_expr
        self.history: deque[Rendered] = deque(maxlen=history)
        self.readers: set[Reader] = set()
        self.latest: dict[str, Rendered] = {}
        """The newest sample of each key, for GET (only for a concrete key expression)."""
        self.arrived = asyncio.Event()
        self.used = time.monotonic()
        self.skipped = 0
        """Samples lost between Zenoh's thread and the loop (the loop fell behind)."""
        self._render = render
        self._loop = asyncio.get_running_loop()
        self._backlog: deque[Raw] = deque(maxlen=CHANNEL_BACKLOG)
        self._lock = threading.Lock()
        self._wake = asyncio.Event()
        self._wakeup = LoopWakeup(self._loop, self._wake.set)
        self._closed = False
        self._keep_latest = "*" not in key_expr
        self._declared: list[object] = []
        if samples:
            # "Every key of a robot" leaves camera/frames out: a subscriber that reaches it turns the
            # camera's full-rate stream on (the robot's page follows icefloe/<robot>/**, and shows
            # camera/image). Asked by name (camera/frames, camera/*), it is followed.
            for expr in keys.without_frames(key_expr):
                self._declared.append(session.declare_subscriber(expr, self._on_sample))
        if liveliness:
            self._declared.append(session.liveliness().declare_subscriber(key_expr, self._on_sample, history=True))
        self._pump = asyncio.create_task(self._run())

    def _on_sample(self, sample: zenoh.Sample) -> None:
        # Zenoh's thread: copy, append to a bounded deque, wake the loop (once for all the samples
        # that come before it looks: `LoopWakeup`). Never block.
        raw = Raw(str(sample.key_expr), sample.payload.to_bytes(), str(sample.encoding), stamp_text(sample.timestamp),
                  "DELETE" if sample.kind == zenoh.SampleKind.DELETE else "PUT")
        with self._lock:  # also keeps `close` from closing the wake-up while it is signalled
            if self._closed:
                return
            if len(self._backlog) == self._backlog.maxlen:
                self.skipped += 1
            self._backlog.append(raw)
            self._wakeup.signal()

    async def _run(self) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()  # before taking the backlog: a sample after this wakes us again
            with self._lock:
                raws = list(self._backlog)
                self._backlog.clear()
            for raw in raws:
                rendered = self._render(raw)
                if rendered is None:
                    continue
                if self._keep_latest:
                    self.latest[rendered.key] = rendered
                    self.arrived.set()
                if self.history.maxlen:
                    self.history.append(rendered)
                for reader in self.readers:
                    reader.offer(rendered)
            await asyncio.sleep(0)  # let the readers' writers run between bursts

    def reader(self, rate: float | None = None) -> Reader:
        reader = Reader(self, rate)
        for sample in self.history:
            reader.offer(sample)
        self.readers.add(reader)
        self.used = time.monotonic()
        return reader

    def drop(self, reader: Reader) -> None:
        reader.close()
        self.readers.discard(reader)
        self.used = time.monotonic()

    def close(self) -> None:
        self._pump.cancel()
        for reader in list(self.readers):
            reader.close()
        for item in self._declared:
            with contextlib.suppress(Exception):
                item.undeclare()  # type: ignore[attr-defined]
        self._declared.clear()
        with self._lock:  # a Zenoh thread may still be delivering a sample: it finds the channel closed
            self._closed = True
            self._wakeup.close()


class Busy(Exception):
    """Too many key expressions followed at once."""


class Hub:
    """The channels of one Zenoh session, by key expression; the unused ones are closed."""

    def __init__(self, session: zenoh.Session, render: Render, *, max_channels: int = MAX_CHANNELS,
                 idle_s: float = IDLE_S) -> None:
        self.session = session
        self.render = render
        self.max_channels = max_channels
        self.idle_s = idle_s
        self.channels: dict[tuple[str, bool], Channel] = {}
        self.pinned: set[tuple[str, bool]] = set()
        """Channels kept open for good (`pin`)."""
        self._janitor: asyncio.Task[None] | None = None
        self._warn = LimitedLog(log)

    def channel(self, key_expr: str, *, samples: bool = True, liveliness: bool = False) -> Channel:
        """The channel of ``key_expr`` (made if needed); `Busy` if there are too many."""
        if self._janitor is None:
            self._janitor = asyncio.create_task(self._sweep())
        key = (key_expr, liveliness)
        channel = self.channels.get(key)
        if channel is None:
            self._close_idle()
            if len(self.channels) >= self.max_channels:
                self._warn.warning("HTTP bridge full", "HTTP bridge: %d key expressions followed already; "
                                   "refused %s", len(self.channels), printable(key_expr))
                raise Busy(f"the HTTP bridge follows {len(self.channels)} key expressions already: try again later")
            channel = self.channels[key] = Channel(self.session, key_expr, self.render, samples=samples,
                                                   liveliness=liveliness)
        channel.used = time.monotonic()
        return channel

    def pin(self, key_expr: str, history: int) -> Channel:
        """Follow ``key_expr`` from now on for good, keeping its last ``history`` samples (so a page
        opened later still shows the last log lines)."""
        channel = self.channels[(key_expr, False)] = Channel(self.session, key_expr, self.render, history=history)
        self.pinned.add((key_expr, False))
        return channel

    def readers(self) -> int:
        return sum(len(c.readers) for c in self.channels.values())

    def _close_idle(self) -> None:
        now = time.monotonic()
        for key, channel in list(self.channels.items()):
            if not channel.readers and now - channel.used > self.idle_s and key not in self.pinned:
                channel.close()
                del self.channels[key]

    async def _sweep(self) -> None:
        while True:
            await asyncio.sleep(self.idle_s / 2)
            self._close_idle()

    def close(self) -> None:
        if self._janitor is not None:
            self._janitor.cancel()
        for channel in self.channels.values():
            channel.close()
        self.channels.clear()
