"""PenguinPi backend (host side): the AVR board over its 115200-baud serial datagram link.

The board runs its own 50 Hz wheel PI controller; we send velocity *demands*
(10 · demand = encoder counts/s, dithered so the average is exact:
`control.DemandDither`) and read encoder
counts back with MULTI_SET_VEL_GET_ENC (set payload right-then-left, reply
left-then-right). A 7-byte request and 9-byte reply take ~1.4 ms on the wire,
so this exchange runs at ``hwbridge.serial_rate_hz`` (200 Hz), not at the
cycle rate.

The cycle never waits on the link: each period it reads whatever bytes have
arrived (non-blocking), feeds them to `icefloe.wire.penguinpi.Parser`
(frames vs the board's text lines), and writes at most one new request when
none is in flight. One GET in flight at a time, matched by address and opcode:
a reply that matches nothing (late, duplicated) is counted, not used.

Around the wheel exchange, about 10 Hz each: battery voltage and current
(ADC_GET_SMOOTH), the user button S4 (HAT_GET_BUTTON) and the DIP switch
(HAT_GET_DIP). LED, LED array, screen and text commands are SETs: the board
never acknowledges them, so they are written between requests.
"""

from __future__ import annotations

import contextlib
import time
from collections import deque

import serial

from icefloe.config import RobotConfig
from icefloe.errors import BoardError
from icefloe.wire import penguinpi as ppi
from icefloe.wire.penguinpi import (
    AdcOp,
    Address,
    Frame,
    HatOp,
    LedOp,
    MultiOp,
    ParseError,
    TextLine,
)

from .board import MSG_BOARD, MSG_WARNING, Board, Say
from .control import DemandDither, SpeedEstimator, Unwrapper, metres_per_tick
from .shm import IO_LED, IO_LEDARRAY, IO_SCREEN, IO_TEXT

BYTE_NS = 10 * 1_000_000_000 // 115200
"""One byte (start + 8 data + stop bits) at 115200 baud, ns (~87 µs)."""
REPLY_TIMEOUT_NS = 20_000_000
"""A GET with no reply after this long is counted as a timeout and forgotten."""
POLL_PERIOD_NS = 25_000_000
"""Slow polls, round-robin over 4 readings: each one at 10 Hz."""
LED_ADDRESS = {1: Address.AD_LED_R, 2: Address.AD_LED_2, 3: Address.AD_LED_3, 4: Address.AD_LED_4}
"""`Led.led` number -> firmware address."""
TEXT_CHUNK = 32
"""Bytes of user text per write: well inside the firmware's 64-byte receive ring."""
_TEXT_OK = frozenset(range(0x20, 0x7F)) | {0x0A, 0x0C}

# The slow polls: (address, opcode), in the order they take turns.
POLLS = (
    (Address.AD_ADC_V, AdcOp.ADC_GET_SMOOTH),
    (Address.AD_HAT, HatOp.HAT_GET_BUTTON),
    (Address.AD_ADC_C, AdcOp.ADC_GET_SMOOTH),
    (Address.AD_HAT, HatOp.HAT_GET_DIP),
)


def board_text(text: bytes) -> bytes:
    """User text made safe for the firmware: printable ASCII, ``\\n`` and ``\\f`` only.

    0x11 would start a datagram and 0x00 is ignored; other control bytes and
    non-ASCII render as garbage glyphs on the OLED.
    """
    return bytes(b for b in text if b in _TEXT_OK)


class PenguinPiBoard(Board):
    """The PenguinPi over pyserial (a real port, or the simulator's pseudo-terminal)."""

    name = "penguinpi"

    def __init__(self, config: RobotConfig, say: Say) -> None:
        super().__init__(config, say)
        hw = config.hwbridge
        self.geometry = config.geometry
        self.port_name = config.board.serial_port
        self.exchange_period_ns = int(1e9 / hw.serial_rate_hz)
        k = metres_per_tick(config.geometry)
        self._speed = (SpeedEstimator(hw.speed_window_s, k), SpeedEstimator(hw.speed_window_s, k))
        self._unwrap = (Unwrapper(), Unwrapper())
        self._dither = (DemandDither(config.geometry), DemandDither(config.geometry))
        self._ser: serial.Serial | None = None
        self._parser = ppi.Parser()
        self._inflight: tuple[int, int] | None = None
        self._inflight_deadline = 0
        self._next_exchange = 0
        self._next_poll = 0
        self._was_stopped = True
        self._poll_index = 0
        self._outbox: deque[bytes] = deque(maxlen=64)
        self._unsent = b""

    # ------------------------------------------------------------------ link

    def open(self, now_ns: int) -> None:
        self.close()
        try:
            # exclusive: a second process (an old ppweb, a second hwbridge) cannot open the port.
            self._ser = serial.Serial(self.port_name, self.config.board.baud, timeout=0,
                                      write_timeout=0, exclusive=True)
            self._ser.reset_input_buffer()
        except (serial.SerialException, OSError, ValueError) as exc:
            self._ser = None
            raise BoardError(f"{self.port_name}: cannot open: {exc}") from None
        self._parser.reset()
        self._inflight = None
        self._unsent = b""
        for unwrap in self._unwrap:
            unwrap.rebase()
        for speed in self._speed:
            speed.reset()
        self._write(ppi.encode_frame(Address.AD_MULTI, MultiOp.MULTI_ALL_STOP))
        self._next_exchange = self._next_poll = now_ns

    def close(self) -> None:
        if self._ser is not None:
            with contextlib.suppress(Exception):
                self._ser.close()
            self._ser = None

    def stop(self) -> None:
        """MULTI_ALL_STOP, waiting until it has left (a few hundred µs)."""
        if self._ser is None:
            return
        with contextlib.suppress(Exception):
            self._ser.write_timeout = 0.05
            self._ser.write(self._unsent + ppi.encode_frame(Address.AD_MULTI, MultiOp.MULTI_ALL_STOP))
            self._ser.flush()
        self._unsent = b""

    def _write(self, data: bytes) -> None:
        """Non-blocking write; whatever the driver did not take goes first next time."""
        assert self._ser is not None
        try:
            n = self._ser.write(data)
        except (serial.SerialException, OSError) as exc:
            raise BoardError(f"{self.port_name}: write failed: {exc}") from None
        n = len(data) if n is None else n
        self._unsent = data[n:]

    # ------------------------------------------------------------------ the cycle

    def cycle(self, now_ns: int, left: float, right: float, stopped: bool, until_ns: int = 0) -> None:
        ser = self._ser
        if ser is None:
            raise BoardError(f"{self.port_name}: not open")
        try:
            data = ser.read(4096)
        except (serial.SerialException, OSError) as exc:
            raise BoardError(f"{self.port_name}: read failed (link lost?): {exc}") from None
        if data:
            self._receive(data, now_ns)
        if stopped and not self._was_stopped:
            self._next_exchange = now_ns  # a stop goes out as soon as the link is free
        self._was_stopped = stopped
        if self._inflight is not None and now_ns > self._inflight_deadline:
            self.timeouts += 1
            self._inflight = None
        if self._unsent:
            self._write(self._unsent)
            return
        if self._inflight is not None:
            return
        if now_ns >= self._next_exchange:
            demand_left = self._dither[0].step(0.0 if stopped else left, now_ns)
            demand_right = self._dither[1].step(0.0 if stopped else right, now_ns)
            self.duty_left, self.duty_right = float(demand_left), float(demand_right)
            self._request(Address.AD_MULTI, MultiOp.MULTI_SET_VEL_GET_ENC,
                          ppi.pack_multi_set(demand_left, demand_right), now_ns)
            # Keep the rate without drifting, but never try to catch up a backlog.
            self._next_exchange = max(self._next_exchange + self.exchange_period_ns,
                                      now_ns + self.exchange_period_ns // 2)
        elif self._outbox:
            self._write(self._outbox.popleft())
        elif now_ns >= self._next_poll:
            address, opcode = POLLS[self._poll_index]
            self._poll_index = (self._poll_index + 1) % len(POLLS)
            self._request(address, opcode, b"", now_ns)
            self._next_poll = now_ns + POLL_PERIOD_NS

    def _request(self, address: int, opcode: int, payload: bytes, now_ns: int) -> None:
        self._write(ppi.encode_frame(address, opcode, payload))
        self._inflight = (address, opcode)
        self._inflight_deadline = now_ns + REPLY_TIMEOUT_NS

    def _receive(self, data: bytes, now_ns: int) -> None:
        for event in self._parser.feed(data):
            if isinstance(event, Frame):
                self._frame(event, now_ns)
            elif isinstance(event, TextLine):
                self._text(event.text)
            elif isinstance(event, ParseError):
                if event.reason == "bad CRC":
                    self.crc_errors += 1
                else:
                    self.garbage_bytes += 1
        self.garbage_bytes += self._parser.garbage
        self._parser.garbage = 0

    def _frame(self, frame: Frame, now_ns: int) -> None:
        if self._inflight != (frame.address, frame.opcode):
            self.unmatched += 1
            return
        self._inflight = None
        try:
            if frame.address == Address.AD_MULTI:
                left, right = ppi.unpack_multi_get(frame.payload)
                self.ticks_left = self._unwrap[0].update(left)
                self.ticks_right = self._unwrap[1].update(right)
                self.sample_ns = now_ns
                self.stamp = _wall_ns(now_ns)
                self.speed_left = self._speed[0].update(now_ns, self.ticks_left)
                self.speed_right = self._speed[1].update(now_ns, self.ticks_right)
                self.exchanges += 1
            elif frame.address == Address.AD_ADC_V:
                self.battery_voltage = ppi.unpack_float(frame.payload) / 1000.0  # mV -> V
            elif frame.address == Address.AD_ADC_C:
                self.battery_current = ppi.unpack_float(frame.payload) / 1000.0  # mA -> A
                if self.battery_voltage:
                    self.battery_ns = now_ns  # a voltage-and-current pair is complete
            elif frame.opcode == HatOp.HAT_GET_BUTTON:
                self.button_presses += ppi.unpack_uint8(frame.payload)  # the read resets the count
            elif frame.opcode == HatOp.HAT_GET_DIP:
                value = ppi.unpack_uint8(frame.payload)
                # Until the first HAT interrupt the firmware returns the nibble unshifted (×16).
                self.dip = value >> 4 if value > 15 else value
        except ValueError:
            self.garbage_bytes += len(frame.payload)  # right address and opcode, wrong length

    def _text(self, line: str) -> None:
        if line.startswith("ERR:"):
            self.board_errors += 1
            self.say(MSG_WARNING, f"PenguinPi: {line}")
        elif line:
            self.say(MSG_BOARD, line)

    # ------------------------------------------------------------------ io

    def io(self, kind: int, a: int, b: int, data: bytes) -> None:
        """LED (a = LED 1..4, b = ms to pulse, 0 = on, -1 = off), LED array, screen, text."""
        if kind == IO_LED and a in LED_ADDRESS:
            if b > 0:
                frame = ppi.encode_frame(LED_ADDRESS[a], LedOp.LED_SET_COUNT, bytes((min(b, 255),)))
            else:
                frame = ppi.encode_frame(LED_ADDRESS[a], LedOp.LED_SET_STATE, bytes((b == 0,)))
            self._outbox.append(frame)
        elif kind == IO_LEDARRAY:
            self._outbox.append(ppi.encode_frame(Address.AD_HAT, HatOp.HAT_SET_LEDARRAY,
                                                 ppi.pack_uint16(a & 0xFFFF)))
        elif kind == IO_SCREEN:
            self._outbox.append(ppi.encode_frame(Address.AD_HAT, HatOp.HAT_SET_SCREEN,
                                                 ppi.pack_uint8(a & 0xFF)))
        elif kind == IO_TEXT:
            text = board_text(data)
            for i in range(0, len(text), TEXT_CHUNK):
                self._outbox.append(text[i:i + TEXT_CHUNK])


def _wall_ns(monotonic_ns: int) -> int:
    """The wall-clock time of a CLOCK_MONOTONIC instant, ns since the epoch."""
    return time.time_ns() - (time.monotonic_ns() - monotonic_ns)
