"""The simulated icoBoard: the FPGA's SPI protocol as a device model.

Two layers:

* `IcoBoardModel` is the board's logic and nothing else: it takes one SPI
  exchange (the host's bytes) at a given time and returns the board's bytes.
  Time comes in as an argument, so the watchdog is tested to the millisecond.
* `IcoBoardSim` puts the model behind a Unix datagram socket at
  ``board.sim_socket``: one request datagram = one full-duplex SPI exchange,
  one reply datagram of the same length back to the sender. A host must bind
  its own socket to receive replies (on Linux ``sock.bind("")`` autobinds an
  abstract address).

What the board does (the frames themselves are in `icefloe.wire.icoboard`):

* v1, as the thesis FPGA: replies carry the counts sampled at the *previous*
  exchange; frames have no checksum, so a corrupt one is used as it arrives;
  there is no watchdog (a dead host leaves the wheels running).
* v2: counts sampled just before replying; a frame with a bad length, CRC or
  opcode is counted and ignored (the next reply says REJECTED); a valid frame
  whose seq is not the previous one + 1 is used, and the gap counted. No valid
  frame for 50 ms -> PWM 0 (WATCHDOG until the next TRANSMIT).
* Both: EXIT -> PWM 0 and stopped; RESET -> PWM 0 and encoder counters 0.

Sensors 0 and 1 are the left and right encoders, actuators 0 and 1 the left and
right motor PWM; further sensors read 0 and further actuators drive nothing.
"""

from __future__ import annotations

import contextlib
import logging
import os
import random
import select
import socket
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from icefloe.config import Board
from icefloe.wire.icoboard import (
    WATCHDOG_S,
    BadCrc,
    BadLength,
    Descriptor,
    FrameError,
    Op,
    Request,
    Status,
    UnexpectedOpcode,
    Wire,
    raw_to_duty,
)

log = logging.getLogger("icefloe.sim.icoboard")


class Wheels(Protocol):
    """The part of `icefloe.sim.world.World` a board drives and reads."""

    def set_duty(self, left: float, right: float) -> None: ...
    def counts(self) -> tuple[int, int]: ...


@dataclass
class Counters:
    """What went wrong on the link, since the board started."""

    frames: int = 0
    """Every exchange received."""
    bad_length: int = 0
    bad_crc: int = 0
    bad_opcode: int = 0
    """Unknown opcodes, and data exchanges before START."""
    seq_gaps: int = 0
    """v2: valid frames whose seq was not the previous one + 1."""
    watchdog_trips: int = 0
    rejected: int = 0
    """Bad frames of any kind, when the board says only that (the gateware)."""

    @property
    def bad_frames(self) -> int:
        return self.bad_length + self.bad_crc + self.bad_opcode + self.rejected


class LineHandles:
    """What every icoBoard model offers the simulator's handles: line noise, and the duty applied."""

    def __init__(self, seed: int) -> None:
        self.pwm: list[int] = []
        """Raw signed duty applied to each actuator now (32767 = 100 %)."""
        self._corrupt_in = 0
        self._corrupt_out = 0
        self._rng = random.Random(seed)

    def corrupt(self, requests: int = 0, replies: int = 0) -> None:
        """Flip one random bit in each of the next ``requests`` frames in / ``replies`` out."""
        self._corrupt_in += requests
        self._corrupt_out += replies

    @property
    def duty(self) -> tuple[float, float]:
        """Duty fraction applied to the left and right wheel, in [-1, 1]."""
        left, right = [*self.pwm, 0, 0][:2]
        return raw_to_duty(left), raw_to_duty(right)

    def _line_in(self, frame: bytes) -> bytes:
        """A request as it arrives: with a flipped bit while `corrupt` asks for it."""
        if not self._corrupt_in:
            return frame
        self._corrupt_in -= 1
        return flip_bit(frame, self._rng)

    def _line_out(self, reply: bytes) -> bytes:
        """A reply as it reaches the host (likewise)."""
        if not self._corrupt_out:
            return reply
        self._corrupt_out -= 1
        return flip_bit(reply, self._rng)


class IcoBoardModel(LineHandles):
    """The board's logic: `exchange` answers one SPI exchange, `tick` runs the watchdog."""

    def __init__(self, world: Wheels, wire: Wire, *, seed: int = 0) -> None:
        """``wire``: the protocol and board shape; ``seed``: the bit flips of `corrupt`."""
        super().__init__(seed)
        self.world = world
        self.wire = wire
        self.counters = Counters()
        self.running = False
        self.pwm = [0] * wire.actuators
        self.last_frame = b""
        """The last request received, as it arrived (after any injected corruption)."""
        self.forced_descriptor: Descriptor | None = None
        """Test handle: what a v2 START reply says instead of the truth."""
        self._offset = (0, 0)              # world counts at the last RESET
        self._sample = (0,) * wire.sensors  # v1: counts sampled at the previous exchange
        self._last_seq = 0                 # v2: seq of the last valid frame (the ack)
        self._status = Status(0)           # v2: WATCHDOG and REJECTED flags
        self._last_valid = 0.0             # v2: time of the last valid frame, s

    # ------------------------------------------------------------------ the board

    def counts(self) -> tuple[int, ...]:
        """Sensor values now: encoder counts since the last RESET (unbounded; the wire wraps)."""
        left, right = self.world.counts()
        values = (left - self._offset[0], right - self._offset[1])
        return (values + (0,) * self.wire.sensors)[: self.wire.sensors]

    def exchange(self, frame: bytes, now: float) -> bytes:
        """One full-duplex SPI exchange at ``now`` (s): the host's bytes in, the board's out."""
        self.counters.frames += 1
        frame = self.last_frame = self._line_in(frame)
        reply = self._v1(frame) if self.wire.version == 1 else self._v2(frame, now)
        return self._line_out(reply)

    def tick(self, now: float) -> None:
        """Called every simulated millisecond: the v2 watchdog."""
        if (self.wire.version == 2 and self.running and any(self.pwm)
                and now - self._last_valid >= WATCHDOG_S):
            self.counters.watchdog_trips += 1
            self._status |= Status.WATCHDOG
            self._set_pwm([0] * self.wire.actuators)
            log.warning("icoBoard watchdog: no valid frame for %.0f ms, PWM off", WATCHDOG_S * 1e3)

    def _v1(self, frame: bytes) -> bytes:
        # Byte 0 leaves before the opcode has arrived: it shows the state (M idle, 3 running).
        head = Op.TRANSMIT if self.running else self.wire.sensors
        try:
            request = self.wire.parse_request(frame)
        except FrameError as exc:
            self._count(exc)
            return self.wire.reply(Op.EMPTY, len(frame), head=head)
        if request.op in (Op.RECEIVE, Op.TRANSMIT) and not self.running:
            self.counters.bad_opcode += 1
            return self.wire.reply(Op.EMPTY, len(frame), head=head)
        # The thesis FPGA sends what it sampled at the previous exchange, then samples anew.
        reply = self.wire.reply(request.op, len(frame), head=head, counts=self._sample)
        self._act(request)
        self._sample = self.counts()
        return reply

    def _v2(self, frame: bytes, now: float) -> bytes:
        status = self._status | (Status.RUNNING if self.running else 0)
        self._status &= ~Status.REJECTED
        op = _opcode(frame)
        try:
            request = self.wire.parse_request(frame)
            if request.op in (Op.RECEIVE, Op.TRANSMIT) and not self.running:
                raise UnexpectedOpcode(f"{request.op.name} before START")
        except FrameError as exc:
            # The board only knows the frame was bad at its last byte: it has already
            # replied in full, so the host hears of it one exchange later (REJECTED).
            self._count(exc)
            self._status |= Status.REJECTED
            return self.wire.reply(op, len(frame), head=status, ack=self._last_seq,
                                   counts=self.counts(), descriptor=self.forced_descriptor)
        reply = self.wire.reply(request.op, len(frame), head=status, ack=self._last_seq,
                                counts=self.counts(), descriptor=self.forced_descriptor)
        if request.op != Op.START and request.seq != (self._last_seq + 1) & 0xFF:
            self.counters.seq_gaps += 1
        self._last_seq, self._last_valid = request.seq, now
        self._act(request)
        return reply

    def _act(self, request: Request) -> None:
        """Apply a valid request to the board's state."""
        if request.op == Op.START:
            self.running = True
        elif request.op == Op.TRANSMIT:
            self._status &= ~Status.WATCHDOG
            self._set_pwm(list(request.duties))
        elif request.op == Op.EXIT:
            self.running = False
            self._set_pwm([0] * self.wire.actuators)
        elif request.op == Op.RESET:
            self._set_pwm([0] * self.wire.actuators)
            self._offset = self.world.counts()

    def _set_pwm(self, raw: list[int]) -> None:
        self.pwm = raw
        self.world.set_duty(*self.duty)

    def _count(self, exc: FrameError) -> None:
        if isinstance(exc, BadCrc):
            self.counters.bad_crc += 1
        elif isinstance(exc, BadLength):
            self.counters.bad_length += 1
        else:
            self.counters.bad_opcode += 1


def flip_bit(frame: bytes, rng: random.Random) -> bytes:
    """``frame`` with one random bit flipped (line noise, for the `corrupt` handles)."""
    if not frame:
        return frame
    bit = rng.randrange(len(frame) * 8)
    out = bytearray(frame)
    out[bit // 8] ^= 1 << (bit % 8)
    return bytes(out)


def _opcode(frame: bytes) -> Op:
    """The opcode a frame starts with (EMPTY if it is empty or unknown)."""
    try:
        return Op(frame[0])
    except (IndexError, ValueError):
        return Op.EMPTY


class BoardModel(Protocol):
    """What `IcoBoardSim` needs of a board model (`IcoBoardModel`, or the gateware's)."""

    counters: Counters
    last_frame: bytes

    def exchange(self, frame: bytes, now: float) -> bytes: ...
    def tick(self, now: float) -> None: ...


TICK_FRAMES = 64
"""At most this many waiting frames answered in one simulated millisecond (after a 50 ms
stall a 1 kHz host has sent 50; the kernel queues fewer, net.unix.max_dgram_qlen)."""


class IcoBoardSim:
    """A board model behind the datagram socket ``board.sim_socket``, with its own I/O thread.

    The model is `IcoBoardModel`, or any object with the same `exchange`, `tick`
    and handles (the gateware: `icefloe.sim.icoboard_gateware.GatewareBoardModel`).
    The simulator's clock calls `tick` once per simulated millisecond; the
    socket thread answers exchanges at the latest tick's time. Both take
    `lock`, which the clock also holds while it steps the world. A model with
    an ``advance(now)`` method gets it called first, without `lock`: its own
    time runs there (it locks what it needs by itself).

    With the Python model, `tick` first answers the frames already waiting in the
    socket, so a frame that arrived before a simulated millisecond is taken in it.
    Otherwise, after this process had been descheduled (a busy machine), the clock
    would catch up (up to 100 steps) first and the board's watchdog fire on frames
    the host had sent in time. The gateware's clock catches up 5 steps at most, so
    its frames never wait that long; and there, answering in the clock's thread
    slowed the simulation on a starved core (docs/sim.md).
    Every frame is read and answered under `lock`, so none overtakes another.
    """

    def __init__(self, world: Wheels, board: Board, *, seed: int = 0,
                 model: BoardModel | None = None) -> None:
        self.path = Path(board.sim_socket)
        self.lock = threading.RLock()
        self.model: BoardModel = model or IcoBoardModel(world, Wire.for_board(board), seed=seed)
        self._now = 0.0
        self._delay = (0.0, 0)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()  # a stale socket from a killed simulator
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._sock.bind(str(self.path))
        self._sock.setblocking(False)  # the thread waits in select, 0.1 s at a time, to notice `close`
        self._holding = False          # a reply `delay_replies` holds back: the frames after it wait
        self._answer_in_tick = not hasattr(self.model, "advance")  # the Python model (above)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="icoboard-sim", daemon=True)
        self._thread.start()
        log.info("icoBoard v%d (M=%d, N=%d) on %s", board.protocol, board.sensors,
                 board.actuators, self.path)

    def delay_replies(self, seconds: float, count: int = 1) -> None:
        """Test handle: answer each of the next ``count`` exchanges ``seconds`` late (the
        exchanges after them wait behind, as behind a stalled link)."""
        if not (0.0 <= seconds <= 10.0) or count < 0:
            raise ValueError(f"seconds must be in [0, 10] and count >= 0, got {seconds}, {count}")
        with self.lock:
            self._delay = (seconds, count)

    def tick(self, now: float) -> None:
        advance = getattr(self.model, "advance", None)
        if advance is not None:
            advance(now)
        with self.lock:
            if self._answer_in_tick and not (self._holding or self._delay[1]):
                self._answer_waiting()
            self._now = now
            self.model.tick(now)

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                if not select.select((self._sock,), (), (), 0.1)[0]:
                    continue
                with self.lock:
                    seconds, count = self._delay
                    if not count:
                        self._answer()
                        continue
                    held = self._receive()
                    if held is None:
                        continue
                    self._delay = (seconds, count - 1)
                    self._holding = True
            except (OSError, ValueError):
                return  # closed
            self._stop.wait(seconds)
            self._send(*held)
            self._holding = False

    def _answer_waiting(self) -> None:
        """Under `lock`: answer the frames waiting in the socket, at most `TICK_FRAMES` (a host
        flooding the socket must not hold the clock); select first: most milliseconds none is
        waiting, and an empty recv costs twice as much."""
        try:
            for _ in range(TICK_FRAMES):
                if not (select.select((self._sock,), (), (), 0)[0] and self._answer()):
                    return
        except (OSError, ValueError):
            pass  # closed

    def _answer(self) -> bool:
        """Under `lock`: answer one waiting frame now; False if none was waiting."""
        held = self._receive()
        if held is not None:
            self._send(*held)
        return held is not None

    def _receive(self) -> tuple[bytes, str | bytes] | None:
        """Under `lock`: one waiting frame, exchanged with the model; its reply and where it goes."""
        try:
            frame, sender = self._sock.recvfrom(4096)
        except BlockingIOError:
            return None
        return self.model.exchange(frame, self._now), sender

    def _send(self, reply: bytes, sender: str | bytes) -> None:
        if sender:
            with contextlib.suppress(OSError):  # the host went away, or its queue is full
                self._sock.sendto(reply, sender)

    def close(self) -> None:
        """Stop the I/O thread, close the socket and remove its file (idempotent)."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(1.0)
        self._sock.close()
        with contextlib.suppress(FileNotFoundError):
            if self.path.is_socket():
                os.unlink(self.path)
        close_model = getattr(self.model, "close", None)
        if close_model is not None:
            close_model()
