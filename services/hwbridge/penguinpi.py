"""PenguinPi backend (host side): the AVR board over its 115200-baud serial datagram link.

The board runs its own 50 Hz wheel PI controller; we send velocity *demands*
(10 · demand = encoder counts/s, dithered so the average is exact:
`control.DemandDither`) and read encoder counts back with MULTI_SET_VEL_GET_ENC
(set payload right-then-left, reply left-then-right). A 7-byte request and
9-byte reply take ~1.4 ms on the wire, so this exchange runs at
``hwbridge.serial_rate_hz`` (200 Hz), not at the cycle rate.

The cycle never waits on the link: each period it reads whatever bytes have
arrived (non-blocking), feeds them to `icefloe.wire.penguinpi.Parser` (frames
vs the board's text lines), and writes at most one new request when none is
in flight.

**Matching replies.** The link has no sequence numbers, and a reply can come
after its request timed out (a slow board, a slow host). Replies come back in
the order of the requests, so after a timeout we *probe*: the next requests
are of other kinds (address and opcode) than the one that timed out, and once
one of them is answered, every earlier reply has come or never will. Until
then, a reply of the timed-out kind is counted as ``late`` and dropped, never
taken for an answer. The wheel exchange has three forms for this
(MULTI_SET_VEL_GET_ENC; MULTI_SET_VEL + MULTI_GET_ENC; MULTI_SET_VEL + another
GET), so it never waits for a probe of its own.

**Stopping.** The firmware's PI controller keeps its integrator when the demand
goes to 0, and its output (the PWM duty, written every 20 ms) stays at 4-7 %:
a motor that hums and creeps. Its integral gain is the one switch it offers:
with Kvi = 0 it clears the integrator (``sum := 0``) and, with Kvp = 0, drives
zero duty at its next 20 ms control step. So while stopped we hold
Kvi = 0 (and Kvp = 0 always); driving sets Kvi = 1, the firmware's default,
first. A stop is *confirmed* once both gains read back as 0 and a 20 ms
control step has passed since the board took them (`stop_confirmed`).

Around the wheel exchange, every 1/60 s in turn: battery voltage and current
(ADC_GET_SMOOTH, so ``hw/battery`` at 10 Hz), the user button S4
(HAT_GET_BUTTON), the DIP switch (HAT_GET_DIP), and both integral gains (a
gain the line lost is written again). LED, LED array, screen and text commands
are SETs: the board never acknowledges them, so they are written between
requests.
"""

from __future__ import annotations

import array
import contextlib
import fcntl
import os
import termios
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
    MotorOp,
    MultiOp,
    ParseError,
    TextLine,
)

from .board import MSG_BOARD, MSG_WARNING, Board, Say
from .control import (
    PENGUINPI_CONTROL_PERIOD_NS,
    DemandDither,
    SpeedEstimator,
    Unwrapper,
    metres_per_tick,
)
from .shm import IO_LED, IO_LEDARRAY, IO_SCREEN, IO_TEXT

BYTE_NS = 10 * 1_000_000_000 // 115200
"""One byte (start + 8 data + stop bits) at 115200 baud, ns (~87 µs)."""
REPLY_TIMEOUT_NS = 20_000_000
"""A GET with no reply after this long is counted as a timeout and its kind probed past."""
QUIET_NS = 3 * REPLY_TIMEOUT_NS
"""When every kind of request has timed out, nothing is asked until the line has been silent
this long: the replies given up on are not coming any more."""
POLL_PERIOD_NS = 1_000_000_000 // 60
"""Slow polls, round-robin over 6 readings: each one at 10 Hz."""
DRIVE_KVI = 1
"""Integral gain while driving: the firmware's default."""
CONFIRM_AFTER_NS = PENGUINPI_CONTROL_PERIOD_NS + 1_000_000
"""A stop is confirmed this long after a reply showed the board had taken the zero gains: by
then its 20 ms control step has run with them (zero duty, integrator cleared)."""
LED_ADDRESS = {1: Address.AD_LED_R, 2: Address.AD_LED_2, 3: Address.AD_LED_3, 4: Address.AD_LED_4}
"""`Led.led` number -> firmware address."""
TEXT_CHUNK = 32
"""Bytes of user text per write: well inside the firmware's 64-byte receive ring."""
_TEXT_OK = frozenset(range(0x20, 0x7F)) | {0x0A, 0x0C}

Kind = tuple[int, int]
"""A request's (address, opcode): all a reply has to say what it answers."""
WHEEL: Kind = (Address.AD_MULTI, MultiOp.MULTI_SET_VEL_GET_ENC)
WHEEL_GET: Kind = (Address.AD_MULTI, MultiOp.MULTI_GET_ENC)
GAIN_RIGHT: Kind = (Address.AD_MOTOR_R, MotorOp.MOTOR_GET_KVI)
GAIN_LEFT: Kind = (Address.AD_MOTOR_L, MotorOp.MOTOR_GET_KVI)
BUTTON: Kind = (Address.AD_HAT, HatOp.HAT_GET_BUTTON)
# The slow polls, in the order they take turns.
POLLS: tuple[Kind, ...] = (
    (Address.AD_ADC_V, AdcOp.ADC_GET_SMOOTH),
    BUTTON,
    (Address.AD_ADC_C, AdcOp.ADC_GET_SMOOTH),
    (Address.AD_HAT, HatOp.HAT_GET_DIP),
    GAIN_RIGHT,
    GAIN_LEFT,
)


def board_text(text: bytes) -> bytes:
    """User text made safe for the firmware: printable ASCII, ``\\n`` and ``\\f`` only.

    0x11 would start a datagram and 0x00 is ignored; other control bytes and
    non-ASCII render as garbage glyphs on the OLED.
    """
    return bytes(b for b in text if b in _TEXT_OK)


def set_gains(kvi: int) -> bytes:
    """MOTOR_SET_KVI to both motors (right, then left)."""
    value = ppi.pack_int16(kvi)
    return (ppi.encode_frame(Address.AD_MOTOR_R, MotorOp.MOTOR_SET_KVI, value)
            + ppi.encode_frame(Address.AD_MOTOR_L, MotorOp.MOTOR_SET_KVI, value))


STOP_FRAMES = set_gains(0) + ppi.encode_frame(Address.AD_MULTI, MultiOp.MULTI_ALL_STOP)
"""Integral gains 0, then demands 0: at its next control step the firmware drives zero duty
and clears both integrators (gains first: a step between the two then already drives 0)."""
OPEN_FRAMES = (STOP_FRAMES + ppi.encode_frame(Address.AD_MOTOR_R, MotorOp.MOTOR_SET_KVP, ppi.pack_int16(0))
               + ppi.encode_frame(Address.AD_MOTOR_L, MotorOp.MOTOR_SET_KVP, ppi.pack_int16(0)))
"""On connecting: stopped, and proportional gains 0 whatever an earlier program set."""


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
        self._fd = -1
        """The port's file descriptor (non-blocking): the cycle reads and writes it directly."""
        self._waiting = array.array("i", [0])
        """FIONREAD's answer: the bytes the line discipline holds (made once: the cycle makes nothing)."""
        self._parser = ppi.Parser()
        # the request in flight, and the kinds we gave up on (see "Matching replies")
        self._inflight: Kind | None = None
        self._inflight_no = 0
        self._inflight_deadline = 0
        self._requests = 0
        """GETs written so far; a reply to GET number n shows the board took every byte before it."""
        self._stale: set[Kind] = set()
        self._heard_ns = 0
        """When bytes last came from the board."""
        # the integral gains (see "Stopping")
        self._gain = 0
        """The integral gain written last (what the board has, unless the line lost it)."""
        self._gain_write = False
        """Write `_gain_wanted` with the next request (a start, or a gain the board lost)."""
        self._gain_request = 0
        """Number of the first GET written after the gains: its reply shows they were taken."""
        self._gain_taken_ns = 0
        """When that reply came (0: not yet)."""
        self._readback: dict[Kind, int | None] = {GAIN_RIGHT: None, GAIN_LEFT: None}
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
        self._fd = self._ser.fileno()  # opened O_NONBLOCK, VMIN = VTIME = 0 (timeout=0)
        self._parser.reset()
        self._inflight = None
        self._stale.clear()
        self._unsent = b""
        for unwrap in self._unwrap:
            unwrap.rebase()
        for speed in self._speed:
            speed.reset()
        self._was_stopped = True
        self.stop_confirmed = False
        self._write(OPEN_FRAMES)
        self._gains_written(0)
        self._next_exchange = self._next_poll = now_ns

    def close(self) -> None:
        self._fd = -1
        if self._ser is not None:
            with contextlib.suppress(Exception):
                self._ser.close()
            self._ser = None

    def stop(self) -> None:
        """MULTI_ALL_STOP and both integral gains 0, waiting until they have left (~1.5 ms).

        The gains stay 0 after we are gone: the firmware then drives zero duty with a
        cleared integrator until someone sets them again (hwbridge does when it drives;
        a reset or power cycle restores the firmware's default Kvi = 1).
        """
        if self._ser is None:
            return
        with contextlib.suppress(Exception):
            self._ser.write_timeout = 0.05
            self._ser.write(self._unsent + STOP_FRAMES)
            self._ser.flush()
        self._unsent = b""

    def _write(self, data: bytes) -> None:
        """Non-blocking write; whatever the driver did not take goes first next time.

        ``os.write`` on the port's descriptor, not pyserial's ``write``: the same system call,
        without the Python around it (a cycle writes a request every 5 ms)."""
        try:
            n = os.write(self._fd, data)
        except BlockingIOError:
            n = 0  # the driver's buffer is full: all of it next time
        except OSError as exc:
            raise BoardError(f"{self.port_name}: write failed: {exc}") from None
        self._unsent = data[n:]

    def _read(self) -> bytes:
        """What has arrived (b"" if nothing), without waiting.

        ``os.read`` on the port's descriptor, not pyserial's ``read``: pyserial asks ``select``
        first and builds a timeout object, three times the cost of the read itself, every period.
        Only when FIONREAD says the line discipline holds bytes: a read that finds none waits, even
        on a non-blocking port, for the kernel's worker that moves bytes just received into the line
        discipline (Linux's ``n_tty_read`` flushes that work first), and the worker runs at normal
        priority: a student's busy loops delayed the real-time cycle behind it by up to 7 ms (traced
        in the box, docs/deploy.md). Bytes the worker has not moved yet are read next period. A port
        whose device has gone (a pseudo-terminal whose far end closed) fails, and the link is lost."""
        try:
            fcntl.ioctl(self._fd, termios.FIONREAD, self._waiting, True)
            if not self._waiting[0]:
                return b""
            return os.read(self._fd, 4096)
        except BlockingIOError:
            return b""
        except OSError as exc:
            raise BoardError(f"{self.port_name}: read failed (link lost?): {exc}") from None

    def _check_connected(self, now_ns: int) -> None:
        """Raise `BoardError` if the port's device is gone (a USB adapter pulled out, a pseudo-terminal
        whose far end closed): FIONREAD then fails. Asked only when a request timed out; pyserial
        asked at every read. Not by ``select``: it waits for the kernel's worker as a read does
        (`_read`; traced: 154 ms beside a student's busy loops). Bytes that did come meanwhile are
        taken as any others."""
        data = self._read()
        if data:
            self._heard_ns = now_ns
            self._receive(data, now_ns)

    # ------------------------------------------------------------------ the cycle

    def cycle(self, now_ns: int, left: float, right: float, stopped: bool, until_ns: int = 0) -> None:
        if self._fd < 0:
            raise BoardError(f"{self.port_name}: not open")
        data = self._read()
        if data:
            self._heard_ns = now_ns
            self._receive(data, now_ns)
        if stopped != self._was_stopped:
            self._was_stopped = stopped
            self.stop_confirmed = False
            self._gain_write = True
            if stopped:
                # SETs are never answered, so they may go while a GET is in flight: at once.
                self._write(self._unsent + STOP_FRAMES)
                self._gains_written(0)
                self.duty_left = self.duty_right = 0.0
                self._next_exchange = now_ns  # then the wheel exchange, as soon as the link is free
        if self._inflight is not None and now_ns > self._inflight_deadline:
            self._check_connected(now_ns)
        if self._inflight is not None and now_ns > self._inflight_deadline:  # still unanswered
            self.timeouts += 1
            self._stale.add(self._inflight)  # its reply may still come: probe past it
            self._inflight = None
        if self._unsent:
            self._write(self._unsent)
        elif self._inflight is None:
            self._next_request(now_ns, 0.0 if stopped else left, 0.0 if stopped else right, stopped)
        self._check_stop(now_ns, stopped)

    def _next_request(self, now_ns: int, left: float, right: float, stopped: bool) -> None:
        """The wheel exchange when due, else (stopping) a gain read-back, else a SET, else a poll.
        Changed gains go out first, in the same write."""
        first = b""
        if self._gain_write:
            first = set_gains(self._gain_wanted)
        if now_ns >= self._next_exchange:
            demand_left = self._dither[0].step(left, now_ns)
            demand_right = self._dither[1].step(right, now_ns)
            self.duty_left, self.duty_right = float(demand_left), float(demand_right)
            speeds = ppi.pack_multi_set(demand_left, demand_right)
            if WHEEL not in self._stale:
                self._request(WHEEL, now_ns, first, speeds)
            else:  # probing past a late wheel reply: set, then ask another way
                first += ppi.encode_frame(Address.AD_MULTI, MultiOp.MULTI_SET_VEL, speeds)
                if (kind := self._fresh(now_ns, WHEEL_GET, *POLLS)) is not None:
                    self._request(kind, now_ns, first)
                else:
                    self._write(first)
            # Keep the rate without drifting, but never try to catch up a backlog. While the
            # cycle rests, every other period: the polls between (battery, button, DIP) take turns.
            period = max(self.exchange_period_ns, 2 * self.rest_period_ns)
            self._next_exchange = max(self._next_exchange + period, now_ns + period // 2)
        elif stopped and self._gain_taken_ns and (kind := self._unread_gain()) is not None:
            self._request(kind, now_ns, first)
        elif self._outbox:
            self._write(first + self._outbox.popleft())
        elif now_ns >= self._next_poll and (
                kind := self._fresh(now_ns, *POLLS[self._poll_index:], *POLLS[:self._poll_index])):
            self._poll_index = (POLLS.index(kind) + 1) % len(POLLS)
            self._request(kind, now_ns, first)
            self._next_poll = now_ns + POLL_PERIOD_NS
        elif first:
            self._write(first)
        else:
            return
        if first:
            self._gains_written(self._gain_wanted, with_request=self._inflight is not None)

    @property
    def _gain_wanted(self) -> int:
        """The integral gain for now: 0 while stopped, the firmware's default while driving."""
        return 0 if self._was_stopped else DRIVE_KVI

    def _fresh(self, now_ns: int, *kinds: Kind) -> Kind | None:
        """The first of ``kinds`` that is not waiting to be probed past, or None."""
        for kind in kinds:
            if kind not in self._stale:
                return kind
        # Every kind timed out and nothing answered (a board far behind, booting, or in its
        # shutdown state): ask again once the line has been silent for a while.
        if now_ns - max(self._heard_ns, self._inflight_deadline) < QUIET_NS:
            return None
        self._stale.clear()
        return kinds[0]

    def _unread_gain(self) -> Kind | None:
        return next((kind for kind, value in self._readback.items()
                     if value is None and kind not in self._stale), None)

    def _gains_written(self, kvi: int, with_request: bool = False) -> None:
        """Both integral gains just went out; ``with_request``: a GET right behind them."""
        self._gain, self._gain_write = kvi, False
        # The reply to the GET written with them, else to the next one, shows they arrived.
        self._gain_request = self._requests if with_request else self._requests + 1
        self._gain_taken_ns = 0
        self._readback = dict.fromkeys(self._readback)

    def _check_stop(self, now_ns: int, stopped: bool) -> None:
        """Stopped, and shown to be: zero gains read back, and a control step since they were taken."""
        if (stopped and not self.stop_confirmed and self._gain == 0 and not self._gain_write
                and self._gain_taken_ns and now_ns >= self._gain_taken_ns + CONFIRM_AFTER_NS
                and all(value == 0 for value in self._readback.values())):
            self.stop_confirmed = True

    def _request(self, kind: Kind, now_ns: int, first: bytes = b"", payload: bytes = b"") -> None:
        """Write ``first`` (SETs), then the GET ``kind``; it is in flight until answered or timed out."""
        self._write(first + ppi.encode_frame(kind[0], kind[1], payload))
        self._requests += 1
        self._inflight, self._inflight_no = kind, self._requests
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
        kind = (frame.address, frame.opcode)
        if kind != self._inflight:
            if kind in self._stale:
                # The reply to the request of this kind that timed out (the only one: a kind is
                # not asked again until then): never taken for the answer to another request.
                self._stale.discard(kind)
                self.late += 1
                if kind == BUTTON:  # its read cleared the board's count: keep the presses
                    with contextlib.suppress(ValueError):
                        self.button_presses += ppi.unpack_uint8(frame.payload)
            else:
                self.unmatched += 1
            return
        # Replies come in request order: everything asked before this one has been answered
        # by now, or never will be.
        self._inflight = None
        self._stale.clear()
        if self._inflight_no >= self._gain_request and not self._gain_taken_ns:
            self._gain_taken_ns = now_ns  # the board had taken the gains before it answered
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
            elif kind in self._readback:
                self._gain_read(kind, ppi.unpack_int16(frame.payload))
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

    def _gain_read(self, kind: Kind, value: int) -> None:
        """A motor's integral gain, read back."""
        if self._gain_write or self._inflight_no < self._gain_request:
            return  # asked before the gains we are about to write, or just wrote
        if value != self._gain:
            # The line lost (or the firmware rejected) our SET: write both again.
            self.say(MSG_WARNING, f"PenguinPi: motor {kind[0]:#x} integral gain is {value}, "
                                  f"not {self._gain}; setting it again")
            self._gain_write = True
            return
        self._readback[kind] = value

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
