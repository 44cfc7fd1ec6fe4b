"""A simulated serial line: a pseudo-terminal whose far end a host opens with pyserial.

The board side reads the master end in its own thread and hands each chunk of
bytes to the board model with the time it arrived; what the board sends goes
out through a writer thread that holds every chunk back for its transmission
time at the configured baud rate (10 bits per byte: start, 8 data, stop), so
replies are never faster than the real link. `LineFaults` injects line noise,
lost bytes, UART errors and delays in either direction, from a seeded random source.
"""

from __future__ import annotations

import contextlib
import os
import queue
import random
import select
import threading
import time
import tty
from collections.abc import Callable
from pathlib import Path

BITS_PER_BYTE = 10
"""8N1 framing: one start bit, eight data bits, one stop bit."""


class LineFaults:
    """Faults on the line, set by tests; thread-safe. "rx" = host to board, "tx" = board to host."""

    def __init__(self, seed: int = 1) -> None:
        self._lock = threading.Lock()
        self._rng = random.Random(seed)
        self._drop = {"rx": 0, "tx": 0}
        self._keep = {"rx": 0, "tx": 0}
        self._noise = {"rx": 0.0, "tx": 0.0}
        self._delay = {"rx": (0.0, 0), "tx": (0.0, 0)}
        self.dropped = {"rx": 0, "tx": 0}
        self.delayed = {"rx": 0, "tx": 0}
        self.corrupted = {"rx": 0, "tx": 0}

    def drop(self, count: int, direction: str = "rx", after: int = 0) -> None:
        """Lose ``count`` bytes in ``direction``, after letting the next ``after`` bytes through."""
        if count < 0 or after < 0:
            raise ValueError("count and after must be >= 0")
        with self._lock:
            self._keep[_check(direction)] = after
            self._drop[direction] = count

    def noise(self, probability: float, direction: str = "rx") -> None:
        """Flip one random bit of each byte with ``probability`` (0 turns noise off)."""
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {probability}")
        with self._lock:
            self._noise[_check(direction)] = probability

    def delay(self, seconds: float, count: int = 1, direction: str = "tx") -> None:
        """Hold each of the next ``count`` chunks (a reply, a text line) ``seconds`` longer; what
        follows waits behind it, as on a real line (a slow board, a stalled link)."""
        if not (0.0 <= seconds <= 10.0) or count < 0:
            raise ValueError(f"seconds must be in [0, 10] and count >= 0, got {seconds}, {count}")
        with self._lock:
            self._delay[_check(direction)] = (seconds, count)

    def hold(self, direction: str) -> float:
        """Seconds to hold the next chunk in ``direction`` back (0 unless `delay` asked for it)."""
        with self._lock:
            seconds, count = self._delay[direction]
            if not count:
                return 0.0
            self._delay[direction] = (seconds, count - 1)
            self.delayed[direction] += 1
            return seconds

    def apply(self, data: bytes, direction: str) -> bytes:
        """The bytes as they come out of the faulty line."""
        with self._lock:
            if not self._drop[direction] and not self._noise[direction]:
                return data
            out = bytearray()
            for byte in data:
                if self._keep[direction]:
                    self._keep[direction] -= 1
                elif self._drop[direction]:
                    self._drop[direction] -= 1
                    self.dropped[direction] += 1
                    continue
                if self._noise[direction] and self._rng.random() < self._noise[direction]:
                    byte ^= 1 << self._rng.randrange(8)
                    self.corrupted[direction] += 1
                out.append(byte)
            return bytes(out)


def _check(direction: str) -> str:
    if direction not in ("rx", "tx"):
        raise ValueError(f'direction must be "rx" or "tx", got {direction!r}')
    return direction


class PtyLink:
    """The board's end of a pseudo-terminal, reachable by the host at ``path`` (a symlink).

    ``on_receive(data, now)`` gets each chunk from the host (after `faults`) at the
    time ``now`` its last byte would have arrived on a real line at ``baud``;
    ``on_idle(now)`` is called at least every millisecond while waiting, so the
    board can time out an incomplete datagram. ``now`` is ``clock()``, seconds.
    """

    def __init__(self, path: str | os.PathLike[str], baud: int,
                 on_receive: Callable[[bytes, float], None],
                 on_idle: Callable[[float], None] | None = None, *,
                 faults: LineFaults | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if baud <= 0:
            raise ValueError(f"baud must be positive, got {baud}")
        self.path = Path(path)
        self.byte_time = BITS_PER_BYTE / baud
        """Seconds one byte occupies the line."""
        self.faults = faults or LineFaults()
        self._on_receive = on_receive
        self._on_idle = on_idle or (lambda now: None)
        self._clock = clock
        self._master, self._slave = os.openpty()
        # Raw mode at once: with the default line discipline the slave would echo
        # our own output back to us until the host's pyserial reconfigures it.
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.slave_name = os.ttyname(self._slave)
        _replace_symlink(self.path, self.slave_name)
        self._stop = threading.Event()
        self._tx: queue.Queue[bytes | None] = queue.Queue()
        self.tx_lost = 0
        """Bytes lost because nobody was reading the host end (its buffer was full)."""
        self._reader = threading.Thread(target=self._read_loop, name="pty-rx", daemon=True)
        self._writer = threading.Thread(target=self._write_loop, name="pty-tx", daemon=True)
        self._reader.start()
        self._writer.start()

    def send(self, data: bytes) -> None:
        """Queue bytes for transmission to the host (returns at once)."""
        self._tx.put(bytes(data))

    def close(self) -> None:
        """Stop both threads, close the terminal, remove the symlink (if still ours)."""
        self._stop.set()
        self._tx.put(None)
        self._reader.join(2.0)
        self._writer.join(2.0)
        with contextlib.suppress(OSError):
            if os.readlink(self.path) == self.slave_name:
                self.path.unlink()
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def _read_loop(self) -> None:
        poller = select.poll()
        poller.register(self._master, select.POLLIN)
        busy_until = 0.0
        while not self._stop.is_set():
            ready = poller.poll(1)                       # ms: the board polls its UART often
            now = self._clock()
            if ready:
                try:
                    data = os.read(self._master, 4096)
                except (BlockingIOError, InterruptedError):
                    data = b""
                except OSError:
                    return                               # terminal closed under us
                data = self.faults.apply(data, "rx")
                if data:
                    # The pty delivers a write at once; a real line needs len(data) byte
                    # times, so the board sees the last byte only when it would arrive.
                    busy_until = (max(now, busy_until) + self.faults.hold("rx")
                                  + len(data) * self.byte_time)
                    self._sleep_until(busy_until)
                    self._on_receive(data, busy_until)
                    continue
            self._on_idle(now)

    def _sleep_until(self, deadline: float) -> None:
        delay = deadline - self._clock()
        if delay > 0:
            time.sleep(delay)

    def _write_loop(self) -> None:
        busy_until = 0.0
        while True:
            chunk = self._tx.get()
            if chunk is None or self._stop.is_set():
                return
            chunk = self.faults.apply(chunk, "tx")
            # The line is busy for len(chunk) byte times after it becomes free.
            busy_until = (max(self._clock(), busy_until) + self.faults.hold("tx")
                          + len(chunk) * self.byte_time)
            self._sleep_until(busy_until)
            self._write(chunk)

    def _write(self, chunk: bytes) -> None:
        """Write without blocking: bytes nobody reads are lost, as on a real UART."""
        view = memoryview(chunk)
        while view:
            try:
                written = os.write(self._master, view)
            except BlockingIOError:
                self.tx_lost += len(view)
                return
            except OSError:
                return
            view = view[written:]


def _replace_symlink(path: Path, target: str) -> None:
    """Point ``path`` at ``target``, replacing a stale symlink but never a real file or device."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.exists() and not path.is_symlink():
        raise FileExistsError(f"{path} exists and is not a symlink; refusing to replace it")
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with contextlib.suppress(FileNotFoundError):
        tmp.unlink()
    tmp.symlink_to(target)
    os.replace(tmp, path)
