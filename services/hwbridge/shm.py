"""The shared-memory layout between hwbridge's bus process and its real-time process.

One block of POSIX shared memory (a file in ``/dev/shm``, mapped with `mmap`) with a fixed
layout (offsets below). Not `multiprocessing.shared_memory`: that one starts a resource-tracker
process for every process that touches a block, 6.5 MiB each on a Pi that has none to spare
(docs/deploy.md, "Memory").
Each field has exactly one writer:

=========  ======================  =========================================
region     writer                  holds
=========  ======================  =========================================
commands   bus process             wheel targets, command time (deadman),
           (two slots)             stop latch, statistics epoch
io ring    bus process (head)      LED / LED array / screen / text commands
           RT process (tail)
state      RT process              encoder sample, speeds, targets, loop and
                                   link statistics, battery, buttons, DIP
histogram  RT process              wake-up latency counts (`control.hist_bin`)
messages   RT process (head)       board text lines and the RT process's own
                                   log lines, read by the bus process
rest       RT process              the number of the cycle's current rest (0:
                                   awake), so the bus side wakes it for a
                                   motion command (`Shared.rest`)
=========  ======================  =========================================

Snapshots (commands, state) are protected by a **seqlock**: the writer makes
the sequence number odd, writes, makes it even again; a reader copies the
fields and retries if the number was odd or changed meanwhile. The writer never
waits for a reader, which is what the real-time side needs. A reader gives up
after `READ_TRIES` tries and counts it (`Shared.stalled_reads`): a writer that
was descheduled in the middle of a write (a starved machine: the cycle without
SCHED_FIFO) does not finish however long the reader spins, so the reader asks
again later (the cycle at its next period, the bus process after a back-off)
instead of taking the CPU the writer needs.

The commands are written more carefully, because their reader is the cycle and a put-off read
would have to stop the wheels for that period: they are **double-buffered**. The bus process
writes the slot the cycle is not reading (with that slot's own seqlock), then publishes it with
one store; the cycle reads the published slot. The bus process writes from several Python threads
(Zenoh's, the event loop's), and Python may switch threads in the middle of a write for
milliseconds; with one slot, each of those periods stopped the wheels, reset the ramp and the
speed loop, and a robot on a busy laptop drove 19 % short. With two, a write in progress is
invisible and the cycle goes on with the last complete one: a stop counts from the moment it is
written whole, and nothing written before it can come back after it. The rings are
single-producer single-consumer: the producer fills a slot, then advances its
head; the consumer reads, then advances its tail.

Memory ordering: every field is a naturally aligned 8-byte word, written with
one store. On x86 (TSO) stores become visible in program order, which is all a
seqlock needs. On ARM64 the hardware may reorder stores; each Python statement
between the stores runs hundreds of instructions and system calls, which in
practice orders them, but a C implementation would need explicit barriers.
"""

from __future__ import annotations

import mmap
import os
import secrets
import struct
import sys
from collections.abc import Sequence
from pathlib import Path

from .control import HIST_BINS

# --------------------------------------------------------------------------- layout

COMMANDS = struct.Struct("<ddqqqq")
"""target_left m/s, target_right m/s, fresh_ns (monotonic ns at which the last motion command
was issued, 0 = none: the deadman counts from it), stop (1 = latched), stats_epoch (bumped by
the bus side to restart the maxima), stop_seq (stops latched so far: the cycle confirms them
by this number)."""

STATE = struct.Struct("<" + "q" * 6 + "d" * 6 + "q" * 12 + "d" * 3 + "q" * 13)
"""See `State` for the field order."""

STATE_FIELDS = (
    # encoder sample
    "stamp", "sample_ns", "ticks_left", "ticks_right", "exchanges", "link_up",
    # wheels (m/s)
    "speed_left", "speed_right", "target_left", "target_right", "duty_left", "duty_right",
    # loop statistics (since start unless noted)
    "cycles", "overruns", "period_sum_ns", "period_max_ns", "latency_max_ns", "stats_epoch",
    "stop_reason", "crc_errors", "timeouts", "unmatched", "garbage_bytes", "board_errors",
    # board readings
    "battery_voltage", "battery_current", "rt_started",
    "battery_ns", "button_presses", "dip", "late", "lost", "io_dropped", "text_lost",
    "pid", "mismatch", "watchdog", "kicks", "stalled_reads", "stop_confirmed",
)  # fmt: skip

IO_SLOTS = 32
IO_DATA = 64
IO_SLOT = struct.Struct(f"<qqqq{IO_DATA}s")
"""kind, a, b, data length, data bytes."""
IO_LED, IO_LEDARRAY, IO_SCREEN, IO_TEXT = 1, 2, 3, 4

MSG_SLOTS = 64
MSG_TEXT = 240
MSG_SLOT = struct.Struct(f"<qq{MSG_TEXT}s")
"""kind (MSG_*), text length, text (UTF-8)."""
MSG_BOARD, MSG_INFO, MSG_WARNING, MSG_ERROR = 1, 2, 3, 4

READ_TRIES = 100
"""Seqlock read attempts before a read gives up for now (`Shared._read`). A write takes a few
microseconds, so a writer that is running is done within a few tries (100 take 0.3-0.7 ms
on the busy build machine); one that is not running does not finish sooner for being waited on."""

CMD_SLOT = 8 + COMMANDS.size
"""A commands slot: its seqlock word, then `COMMANDS`."""

OFF_CMD_SEQ = 0
"""The commands' published version: slot ``version % 2`` holds the latest complete write."""
OFF_CMD = 8
OFF_IO_HEAD = OFF_CMD + 2 * CMD_SLOT
OFF_IO_TAIL = OFF_IO_HEAD + 8
OFF_IO = OFF_IO_TAIL + 8
OFF_STATE_SEQ = OFF_IO + IO_SLOTS * IO_SLOT.size
OFF_STATE = OFF_STATE_SEQ + 8
OFF_HIST = OFF_STATE + STATE.size
OFF_MSG_HEAD = OFF_HIST + 8 * HIST_BINS
OFF_MSG = OFF_MSG_HEAD + 8
OFF_REST = OFF_MSG + MSG_SLOTS * MSG_SLOT.size
"""The cycle's rest: one word, read by the bus side at each motion command (`Shared.rest`)."""
SIZE = OFF_REST + 8

assert len(STATE_FIELDS) == len(STATE.format) - 1, "STATE format and field list disagree"
assert all(off % 8 == 0 for off in (OFF_CMD, OFF_IO, OFF_STATE, OFF_HIST, OFF_MSG, OFF_REST, SIZE)), "unaligned"
assert sys.byteorder == "little", "the words below and the little-endian layouts above must agree"
W_CMD_SEQ, W_IO_HEAD, W_IO_TAIL, W_STATE_SEQ, W_MSG_HEAD, W_REST = (off // 8 for off in (
    OFF_CMD_SEQ, OFF_IO_HEAD, OFF_IO_TAIL, OFF_STATE_SEQ, OFF_MSG_HEAD, OFF_REST))
"""The same words as indices into `Shared.words` (the block as 8-byte integers): what the cycle
reads and writes every period goes through that view, a third of the cost of `struct` calls."""


def block_name(robot: str) -> str:
    """The shared-memory name of a robot's hwbridge (``/dev/shm/icefloe-hwbridge-<robot>``)."""
    return f"icefloe-hwbridge-{robot}"


SHM_DIR = Path("/dev/shm")
"""Where Linux keeps POSIX shared memory (what ``shm_open`` names)."""


class Block:
    """A named block of shared memory mapped into this process: ``buf`` is its bytes."""

    def __init__(self, name: str, fd: int) -> None:
        self.name = name
        self._map = mmap.mmap(fd, SIZE)
        os.close(fd)  # the mapping keeps the memory
        self.buf = memoryview(self._map)

    @classmethod
    def create(cls, name: str) -> Block:
        """A new zeroed block (private to this user); one left behind by a killed hwbridge is replaced."""
        path = SHM_DIR / name
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o600)
        except FileExistsError:
            path.unlink()
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o600)
        os.ftruncate(fd, SIZE)  # a new file reads as zeros
        return cls(name, fd)

    @classmethod
    def attach(cls, name: str) -> Block:
        return cls(name, os.open(SHM_DIR / name, os.O_RDWR))

    def close(self) -> None:
        self.buf.release()
        self._map.close()

    def unlink(self) -> None:
        (SHM_DIR / self.name).unlink(missing_ok=True)


class Shared:
    """A view of the hwbridge shared-memory block: ``Shared.create()`` or ``Shared.attach(name)``."""

    def __init__(self, shm: Block, owner: bool) -> None:
        self.shm = shm
        self.owner = owner
        self.buf = shm.buf
        self.hist = shm.buf[OFF_HIST:OFF_HIST + 8 * HIST_BINS].cast("q")
        """Latency histogram counts, one 8-byte word per bin (written by the RT process only)."""
        self.words = shm.buf.cast("q")
        """The whole block as native 8-byte integers: word ``offset // 8`` is the one at ``offset``
        (each one aligned, so read and written with one load or store, as by `struct`)."""
        self._msg_tail = 0
        self._cmd_version = -1
        self._cmd_values: tuple[float, float, int, int, int, int] = (0.0, 0.0, 0, 0, 0, 0)
        """The commands as last read, and the version they were published as (`read_commands`)."""
        self.stalled_reads = 0
        """Reads this side gave up on because the other side was in the middle of a write for all
        `READ_TRIES` tries (it was descheduled mid-write), since start."""

    @classmethod
    def create(cls, name: str | None = None) -> Shared:
        """A new zeroed block; ``name`` (e.g. `block_name`) lets tools attach to read it (default:
        a name of its own). A block of that name left behind by a killed hwbridge is replaced."""
        return cls(Block.create(name or f"icefloe-hwbridge-{secrets.token_hex(6)}"), owner=True)

    @classmethod
    def attach(cls, name: str) -> Shared:
        """The block another process created. Only its creator unlinks it."""
        return cls(Block.attach(name), owner=False)

    @property
    def name(self) -> str:
        return self.shm.name

    def close(self) -> None:
        self.hist.release()
        self.words.release()
        self.buf = None  # type: ignore[assignment]
        self.shm.close()
        if self.owner:
            self.shm.unlink()

    # ------------------------------------------------------------------ seqlock

    def _word(self, offset: int) -> int:
        return self.words[offset >> 3]

    def _set_word(self, offset: int, value: int) -> None:
        self.words[offset >> 3] = value

    def _copy(self, seq_off: int, layout: struct.Struct, off: int) -> tuple | None:
        """One try at a consistent copy of a snapshot: None if a write was in progress during it."""
        words, at = self.words, seq_off >> 3
        before = words[at]
        if before & 1:
            return None
        values = layout.unpack_from(self.buf, off)
        return values if words[at] == before else None

    def _read(self, seq_off: int, layout: struct.Struct, off: int) -> tuple | None:
        """A consistent copy of a snapshot, or None (counted) when every try found a write in
        progress: the writer was descheduled (or died) half-way. Ask again later."""
        for _ in range(READ_TRIES):
            if (values := self._copy(seq_off, layout, off)) is not None:
                return values
        self.stalled_reads += 1
        return None

    def _write(self, seq_off: int, layout: struct.Struct, off: int, *values: object) -> None:
        words, at = self.words, seq_off >> 3
        seq = words[at]
        words[at] = seq + 1
        layout.pack_into(self.buf, off, *values)
        words[at] = seq + 2

    # ------------------------------------------------------------------ commands (bus -> RT)

    @staticmethod
    def _cmd_slot(version: int) -> int:
        return OFF_CMD + (version % 2) * CMD_SLOT

    def write_commands(self, left: float, right: float, fresh_ns: int, stop: bool,
                       epoch: int, stop_seq: int = 0) -> None:
        """Write the slot the cycle is not reading, then publish it (one writer at a time)."""
        version = self._word(OFF_CMD_SEQ) + 1
        slot = self._cmd_slot(version)
        self._write(slot, COMMANDS, slot + 8, left, right, fresh_ns, int(stop), epoch, stop_seq)
        self._set_word(OFF_CMD_SEQ, version)

    def read_commands(self) -> tuple[float, float, int, int, int, int] | None:
        """(target_left, target_right, fresh_ns, stop, stats_epoch, stop_seq) of the latest
        complete write. A write in progress never holds this up: it goes to the other slot. Only
        a writer that published and began the next write into this very slot during the copy
        makes it look again; None (counted) if that happened on every try.

        While the published version is the one read last time, its slot has not been written
        since (writes go to the other slot, then publish a new version): the copy made then is
        returned without reading the slot again, as in most periods."""
        words = self.words
        version = words[W_CMD_SEQ]
        if version == self._cmd_version:
            return self._cmd_values
        buf = self.buf
        for _ in range(READ_TRIES):  # `_copy` inline
            slot = OFF_CMD + (version & 1) * CMD_SLOT
            before = words[slot >> 3]
            if not before & 1:
                values = COMMANDS.unpack_from(buf, slot + 8)
                if words[slot >> 3] == before:
                    self._cmd_version, self._cmd_values = version, values  # type: ignore[assignment]
                    return values  # type: ignore[return-value]
            version = words[W_CMD_SEQ]  # looked up again on each try
        self.stalled_reads += 1
        return None

    def commands_pending(self) -> bool:
        """RT side: whether a write was published since `read_commands` last read one."""
        return self.words[W_CMD_SEQ] != self._cmd_version

    # ------------------------------------------------------------------ io ring (bus -> RT)

    def push_io(self, kind: int, a: int = 0, b: int = 0, data: bytes = b"") -> bool:
        """Queue an I/O command for the board; False if the ring is full (the caller logs it)."""
        head, tail = self._word(OFF_IO_HEAD), self._word(OFF_IO_TAIL)
        if head - tail >= IO_SLOTS:
            return False
        data = data[:IO_DATA]
        IO_SLOT.pack_into(self.buf, OFF_IO + (head % IO_SLOTS) * IO_SLOT.size,
                          kind, a, b, len(data), data)
        self._set_word(OFF_IO_HEAD, head + 1)
        return True

    def pop_io(self) -> tuple[int, int, int, bytes] | None:
        """The oldest queued I/O command as (kind, a, b, data), or None."""
        words = self.words
        tail = words[W_IO_TAIL]
        if words[W_IO_HEAD] == tail:  # the common case: every period, nothing queued
            return None
        kind, a, b, n, data = IO_SLOT.unpack_from(self.buf, OFF_IO + (tail % IO_SLOTS) * IO_SLOT.size)
        words[W_IO_TAIL] = tail + 1
        return kind, a, b, data[:n]

    # ------------------------------------------------------------------ state (RT -> bus)

    def write_state(self, values: Sequence[float | int]) -> None:
        """Publish a full state snapshot; ``values`` in `STATE_FIELDS` order."""
        words = self.words  # `_write` inline: the cycle writes its state every period
        seq = words[W_STATE_SEQ]
        words[W_STATE_SEQ] = seq + 1
        STATE.pack_into(self.buf, OFF_STATE, *values)
        words[W_STATE_SEQ] = seq + 2

    def read_state(self) -> dict[str, float | int] | None:
        """A consistent copy of the state, by field name; None if the cycle is in the middle of a
        write (see `_read`)."""
        values = self._read(OFF_STATE_SEQ, STATE, OFF_STATE)
        return None if values is None else dict(zip(STATE_FIELDS, values, strict=True))

    # ------------------------------------------------------------------ rest (RT -> bus)

    def set_rest(self, number: int) -> None:
        """RT side: the cycle rests (its ``number``-th rest since start, from 1), or is awake (0)."""
        self.words[W_REST] = number

    def rest(self) -> int:
        """Bus side: the number of the cycle's current rest, 0 while it is awake. One word, one
        load: cheap enough to ask at every motion command (a new number: wake it, `Bridge`)."""
        return self.words[W_REST]

    # ------------------------------------------------------------------ messages (RT -> bus)

    def push_message(self, kind: int, text: str | bytes) -> None:
        """RT side: add a line to the message ring (the oldest is overwritten when it is full)."""
        raw = text.encode("utf-8", "replace") if isinstance(text, str) else text
        raw = raw[:MSG_TEXT]
        head = self._word(OFF_MSG_HEAD)
        MSG_SLOT.pack_into(self.buf, OFF_MSG + (head % MSG_SLOTS) * MSG_SLOT.size, kind, len(raw), raw)
        self._set_word(OFF_MSG_HEAD, head + 1)

    def pop_messages(self) -> tuple[list[tuple[int, str]], int]:
        """Bus side: new lines as (kind, text), and how many were overwritten before we read them."""
        head = self._word(OFF_MSG_HEAD)
        lost = max(0, head - self._msg_tail - MSG_SLOTS)
        self._msg_tail += lost
        out = []
        while self._msg_tail < head:
            kind, n, raw = MSG_SLOT.unpack_from(
                self.buf, OFF_MSG + (self._msg_tail % MSG_SLOTS) * MSG_SLOT.size)
            out.append((kind, raw[:n].decode("utf-8", "replace")))
            self._msg_tail += 1
        return out, lost
