"""The icoBoard SPI protocol: frame builders and parsers for both ends of the wire.

The Pi (host) is SPI controller and clocks every exchange. SPI is full duplex:
while the host shifts its frame out, the board shifts its reply back, so a
reply is always exactly as long as the request. hwbridge uses the host side of
this module, the simulator's board model the board side; this file is the one
definition of the bytes.

Shared by both versions: byte 0 of a request is an opcode (`Op`), values are
``B = 2`` bytes per peripheral, big-endian. ``M`` = number of sensors
(encoders), ``N`` = number of actuators (PWM). Encoder counts are unsigned
16-bit and wrap (0..65535); actuator values are signed 16-bit duty, sign =
direction, 32767 = 100 %.

Version 1 (the thesis's protocol, Table 4.1/4.2, as its FPGA built it)::

    exchange   length          host sends                 board sends
    START      1               01                         M
    RECEIVE    1 + B*M         02 00..                    03 + M counts
    TRANSMIT   1 + B*max(M,N)  03 + N duties (0-padded)   03 + M counts (0-padded)
    EXIT       1               04                         03   (the reply is cut)
    RESET      1               05                         03

The board's byte 0 leaves while the opcode is still arriving, so it can only
depend on the board's state: M before START (and after EXIT), 03 while
running. A v1 board left running by a host that died answers START with 03, so
a host sends EXIT before START. The v1 FPGA returns the counts it sampled at the *previous* exchange
(one period late). There is no checksum: a corrupt v1 frame is used as it is.

Version 2 (ours: the thesis's §6.2 recommendations, built). Every frame is::

    byte 0      host: opcode              board: status (bits below)
    byte 1      host: seq (0..255, +1     board: ack = seq of the last valid
                per frame, wrapping)      frame it accepted before this one
    2 .. L-2    body (below)              body (below)
    L-1         CRC-8/AUTOSAR over bytes 0 .. L-2 (poly 0x2F, init 0xFF, xorout 0xFF)

    exchange   L               host body                  board body
    START      10              7 zero bytes               M, N, B, hash (uint32 BE)
    RECEIVE    3 + B*M         zeros                      M counts, sampled just before
    TRANSMIT   3 + B*max(M,N)  N duties (0-padded)        M counts (0-padded), likewise
    EXIT       3               (none)                     (none)
    RESET      3               (none)                     (none)
    EMPTY      3               (none)                     (none)

Board status bits: ``RUNNING`` (started and not exited), ``WATCHDOG`` (the
board stopped the wheels because no valid frame came for 50 ms; cleared by the
next TRANSMIT), ``REJECTED`` (the previous frame it received was bad). The
board knows the opcode after byte 0, so from byte 1 on its reply can depend on
it, and it can put the CRC at the right place. It cannot echo the seq it is
receiving in the same byte, hence the ack of the *previous* valid frame: the
host checks it equals the seq it sent last time, which catches frames lost or
rejected on the way in. The CRC's non-zero init and xorout make a stuck-low
(all 0x00) or stuck-high (all 0xFF) MISO line fail the check.

The START hash is CRC-32 (zlib) of the peripheral list written as
``"encoder,encoder|pwm,pwm"`` (sensors, then actuators), so two boards with the
same counts but different peripherals do not match (thesis §6.2.3). `Peripherals` is
that list, shared by hwbridge's check and the gateware that answers START.
"""

from __future__ import annotations

import enum
import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass

from ..config import Board
from ..errors import BoardError, BoardMismatch

WIDTH = 2
"""B: bytes per peripheral value."""
DUTY_FULL = 32767
"""Raw duty of 100 %."""
WATCHDOG_S = 0.050
"""v2 board watchdog: no valid frame for this long (s) -> PWM to 0."""
START_LENGTH_V2 = 10
"""Length of a v2 START exchange, bytes."""
HEADER_V2 = 2
"""v2 bytes before the body: opcode/status and seq/ack."""


class Op(enum.IntEnum):
    """Request opcodes (byte 0 of every host frame), thesis Table 4.1."""

    EMPTY = 0
    START = 1
    RECEIVE = 2
    TRANSMIT = 3
    EXIT = 4
    RESET = 5


class Status(enum.IntFlag):
    """v2 board status, byte 0 of every board frame."""

    RUNNING = 0x01
    WATCHDOG = 0x02
    REJECTED = 0x04


# ---------------------------------------------------------------------------------- errors


class FrameError(BoardError):
    """A frame on the icoBoard link was not what the protocol allows."""


class BadLength(FrameError):
    """A frame's length does not match its opcode."""


class BadCrc(FrameError):
    """A v2 frame's CRC-8 does not match its bytes."""


class UnexpectedOpcode(FrameError):
    """An opcode that is unknown, or not allowed in the current state."""


class SequenceGap(FrameError):
    """v2: sequence numbers skipped, i.e. frames were lost or rejected on the way."""


# ---------------------------------------------------------------------------------- CRC-8


def _crc8_table(poly: int) -> bytes:
    table = bytearray(256)
    for byte in range(256):
        reg = byte
        for _ in range(8):
            reg = ((reg << 1) ^ poly) & 0xFF if reg & 0x80 else (reg << 1) & 0xFF
        table[byte] = reg
    return bytes(table)


_CRC8 = _crc8_table(0x2F)


def crc8(data: bytes | bytearray | memoryview) -> int:
    """CRC-8/AUTOSAR of ``data`` (check value for b"123456789" is 0xDF)."""
    reg = 0xFF
    for byte in data:
        reg = _CRC8[reg ^ byte]
    return reg ^ 0xFF


# ---------------------------------------------------------------------------------- values


def duty_to_raw(duty: float) -> int:
    """Signed duty fraction in [-1, 1] -> raw signed 16-bit value (clamped)."""
    return max(-DUTY_FULL, min(DUTY_FULL, round(duty * DUTY_FULL)))


def raw_to_duty(raw: int) -> float:
    """Raw signed 16-bit duty -> fraction in [-1, 1] (-32768 clamps to -1)."""
    return max(-1.0, raw / DUTY_FULL)


def wrap16(count: int) -> int:
    """An unbounded encoder count as the board sends it: 16 bits, wrapping."""
    return count & 0xFFFF


def delta16(new: int, old: int) -> int:
    """Counts moved between two wrapped 16-bit readings (exact while |motion| < 32768)."""
    return (new - old + 0x8000) % 0x10000 - 0x8000


def peripheral_hash(sensors: Sequence[str], actuators: Sequence[str]) -> int:
    """CRC-32 of the peripheral list, e.g. (["encoder", "encoder"], ["pwm", "pwm"])."""
    text = ",".join(sensors) + "|" + ",".join(actuators)
    return zlib.crc32(text.encode())


@dataclass(frozen=True)
class Peripherals:
    """A board's peripheral list (thesis §6.2.2, §6.2.3): the one definition of what is on the board.

    The gateware (``icefloe.gateware``) builds one quadrature decoder per ``"encoder"``
    and one PWM + direction output per ``"pwm"`` from it, and answers START with its
    `descriptor`; hwbridge checks that reply against the descriptor of the list its
    config gives (`Wire.descriptor`). Both ends call this class, so they cannot drift.
    """

    sensors: tuple[str, ...] = ("encoder", "encoder")
    """Sensor kinds in wire order (sensor 0 = left wheel encoder, 1 = right)."""
    actuators: tuple[str, ...] = ("pwm", "pwm")
    """Actuator kinds in wire order (actuator 0 = left motor, 1 = right)."""

    @classmethod
    def of(cls, sensors: int, actuators: int) -> Peripherals:
        """``sensors`` encoders and ``actuators`` PWM outputs (what a robot config describes)."""
        return cls(("encoder",) * sensors, ("pwm",) * actuators)

    @classmethod
    def for_board(cls, board: Board) -> Peripherals:
        """The peripheral list of the ``[board]`` table of a robot config."""
        return cls.of(board.sensors, board.actuators)

    @property
    def hash(self) -> int:
        return peripheral_hash(self.sensors, self.actuators)

    @property
    def descriptor(self) -> Descriptor:
        """What a board with this list says in its v2 START reply."""
        return Descriptor(len(self.sensors), len(self.actuators), WIDTH, self.hash)


# ---------------------------------------------------------------------------------- frames


@dataclass(frozen=True)
class Descriptor:
    """What a v2 board says about itself in its START reply."""

    sensors: int
    """M."""
    actuators: int
    """N."""
    width: int
    """B, bytes per value."""
    hash: int
    """`peripheral_hash` of the board's peripheral list."""

    @classmethod
    def of(cls, sensors: int, actuators: int) -> Descriptor:
        """The descriptor of a board with ``sensors`` encoders and ``actuators`` PWM outputs."""
        return Peripherals.of(sensors, actuators).descriptor

    def check(self, expected: Descriptor) -> None:
        """Raise `BoardMismatch` naming every difference from ``expected`` (the config)."""
        why = [f"{name} {got} (config says {want})"
               for name, got, want in (("sensors M =", self.sensors, expected.sensors),
                                       ("actuators N =", self.actuators, expected.actuators),
                                       ("bytes per value B =", self.width, expected.width))
               if got != want]
        if self.hash != expected.hash:
            why.append(f"peripheral hash {self.hash:#010x} (config gives {expected.hash:#010x})")
        if why:
            raise BoardMismatch("icoBoard START descriptor does not match the config: "
                                + "; ".join(why))


@dataclass(frozen=True)
class Request:
    """A host frame, as the board reads it."""

    op: Op
    seq: int = 0
    """v2 sequence number (0 in v1)."""
    duties: tuple[int, ...] = ()
    """TRANSMIT: N raw signed duties."""


@dataclass(frozen=True)
class Reply:
    """A board frame, as the host reads it."""

    head: int
    """v1: byte 0 (M for START, 3 otherwise); v2: the `Status` bits."""
    ack: int = 0
    """v2: seq of the last valid frame the board accepted before this exchange."""
    counts: tuple[int, ...] = ()
    """RECEIVE/TRANSMIT: M wrapped 16-bit encoder counts."""
    descriptor: Descriptor | None = None
    """v2 START: the board's descriptor."""


@dataclass(frozen=True)
class Wire:
    """The icoBoard protocol for one board shape: ``Wire(version, sensors, actuators)``."""

    version: int
    """1 or 2."""
    sensors: int = 2
    """M."""
    actuators: int = 2
    """N."""

    def __post_init__(self) -> None:
        if self.version not in (1, 2):
            raise ValueError(f"icoBoard protocol version must be 1 or 2, not {self.version}")
        if not (0 <= self.sensors <= 255 and 0 <= self.actuators <= 255):
            raise ValueError("icoBoard sensors and actuators must be 0..255")

    @classmethod
    def for_board(cls, board: Board) -> Wire:
        """The wire of a board in the robot config (its protocol, sensors and actuators)."""
        return cls(board.protocol, board.sensors, board.actuators)

    @property
    def slots(self) -> int:
        """Values in a TRANSMIT body: max(M, N)."""
        return max(self.sensors, self.actuators)

    @property
    def peripherals(self) -> Peripherals:
        return Peripherals.of(self.sensors, self.actuators)

    @property
    def descriptor(self) -> Descriptor:
        return self.peripherals.descriptor

    def length(self, op: Op) -> int:
        """Bytes in one exchange of ``op`` (request and reply alike)."""
        values = {Op.RECEIVE: self.sensors, Op.TRANSMIT: self.slots}.get(op, 0)
        if self.version == 1:
            return 1 + WIDTH * values
        if op == Op.START:
            return START_LENGTH_V2
        return HEADER_V2 + WIDTH * values + 1

    # ------------------------------------------------------------------ host side

    def request(self, op: Op, *, seq: int = 0, duties: Sequence[int] = ()) -> bytes:
        """The host's frame for ``op``; ``duties`` are N raw values (TRANSMIT only)."""
        if op == Op.TRANSMIT and len(duties) != self.actuators:
            raise ValueError(f"TRANSMIT takes {self.actuators} duties, got {len(duties)}")
        frame = bytearray(self.length(op))
        frame[0] = op
        start = 1 if self.version == 1 else HEADER_V2
        for i, duty in enumerate(duties if op == Op.TRANSMIT else ()):
            struct.pack_into(">h", frame, start + WIDTH * i, max(-32768, min(32767, duty)))
        if self.version == 2:
            frame[1] = seq & 0xFF
            frame[-1] = crc8(memoryview(frame)[:-1])
        return bytes(frame)

    def parse_reply(self, op: Op, frame: bytes) -> Reply:
        """Read the board's reply to our ``op`` frame; raises a `FrameError` if it is bad."""
        self._check_length(op, frame, "reply")
        if self.version == 1:
            if op in (Op.RECEIVE, Op.TRANSMIT):
                return Reply(frame[0], counts=self._counts(frame, 1))
            return Reply(frame[0])
        self._check_crc(frame, "reply")
        head, ack = frame[0], frame[1]
        if op == Op.START:
            m, n, b, hash_ = struct.unpack_from(">BBBI", frame, HEADER_V2)
            return Reply(head, ack, descriptor=Descriptor(m, n, b, hash_))
        if op in (Op.RECEIVE, Op.TRANSMIT):
            return Reply(head, ack, counts=self._counts(frame, HEADER_V2))
        return Reply(head, ack)

    def check_start(self, reply: Reply) -> None:
        """Host: refuse to run when the START reply does not match the config (`BoardMismatch`)."""
        if self.version == 1:
            if reply.head != self.sensors:
                hint = (" (or it is still running from an earlier host: send EXIT before START)"
                        if reply.head == Op.TRANSMIT else "")
                raise BoardMismatch(f"icoBoard START: board has M = {reply.head} sensors, "
                                    f"config says {self.sensors}{hint}")
            return
        if reply.descriptor is None:
            raise UnexpectedOpcode("check_start needs the reply to a v2 START")
        reply.descriptor.check(self.descriptor)

    # ------------------------------------------------------------------ board side

    def parse_request(self, frame: bytes) -> Request:
        """Read a host frame; raises a `FrameError` if it is bad (the board then ignores it)."""
        if not frame:
            raise BadLength("empty frame")
        try:
            op = Op(frame[0])
        except ValueError:
            raise UnexpectedOpcode(f"unknown opcode {frame[0]}") from None
        self._check_length(op, frame, "request")
        if self.version == 2:
            self._check_crc(frame, "request")
        duties: tuple[int, ...] = ()
        if op == Op.TRANSMIT:
            start = 1 if self.version == 1 else HEADER_V2
            duties = struct.unpack_from(f">{self.actuators}h", frame, start)
        return Request(op, frame[1] if self.version == 2 else 0, duties)

    def reply(self, op: Op, length: int, *, head: int, ack: int = 0,
              counts: Sequence[int] = (), descriptor: Descriptor | None = None) -> bytes:
        """The board's frame for an exchange of ``length`` bytes that started with opcode ``op``.

        ``head`` is byte 0 (v1: M or 3; v2: status), ``counts`` the M unbounded or
        wrapped encoder counts to send (RECEIVE/TRANSMIT), ``descriptor`` what a
        v2 START reply says (default: this wire's own). A frame of the wrong
        length gets ``head`` and zeros: the board does not know what to send.
        """
        frame = bytearray(length)
        if length == 0:
            return b""
        frame[0] = head & 0xFF
        if length != self.length(op):
            return bytes(frame)
        start = 1 if self.version == 1 else HEADER_V2
        if op in (Op.RECEIVE, Op.TRANSMIT):
            for i, count in enumerate(counts[: self.sensors]):
                struct.pack_into(">H", frame, start + WIDTH * i, wrap16(count))
        if self.version == 2:
            frame[1] = ack & 0xFF
            if op == Op.START:
                d = descriptor or self.descriptor
                struct.pack_into(">BBBI", frame, HEADER_V2, d.sensors, d.actuators, d.width, d.hash)
            frame[-1] = crc8(memoryview(frame)[:-1])
        return bytes(frame)

    # ------------------------------------------------------------------ helpers

    def _check_length(self, op: Op, frame: bytes, what: str) -> None:
        want = self.length(op)
        if len(frame) != want:
            raise BadLength(f"v{self.version} {op.name} {what}: {len(frame)} bytes, "
                            f"expected {want}")

    @staticmethod
    def _check_crc(frame: bytes, what: str) -> None:
        got, want = frame[-1], crc8(frame[:-1])
        if got != want:
            raise BadCrc(f"v2 {what}: CRC {got:#04x}, computed {want:#04x}")

    def _counts(self, frame: bytes, start: int) -> tuple[int, ...]:
        return struct.unpack_from(f">{self.sensors}H", frame, start)


def check_sequence(expected: int, got: int) -> None:
    """Raise `SequenceGap` unless ``got`` is ``expected`` (both mod 256)."""
    if (got - expected) & 0xFF:
        raise SequenceGap(f"seq {got & 0xFF}, expected {expected & 0xFF} "
                          f"({(got - expected) & 0xFF} frame(s) missing)")


def check_ack(previous_seq: int, reply: Reply) -> None:
    """Host, v2: a reply must acknowledge the frame we sent one exchange earlier."""
    if reply.ack != previous_seq & 0xFF:
        raise SequenceGap(f"board acknowledged seq {reply.ack}, we sent {previous_seq & 0xFF} "
                          "(that frame was lost or rejected)")
