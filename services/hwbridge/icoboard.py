"""icoBoard backend (host side): one SPI exchange per cycle, PI velocity control per wheel.

The FPGA only counts encoder edges and drives PWM; the speed loop runs here,
in the real-time cycle: measured speed from encoder differences
(`control.SpeedEstimator`), a `control.PIController` per wheel, output clamped
to the duty range. Frames are built and checked by `icefloe.wire.icoboard`
(protocol v1 or v2 per ``board.protocol``).

Transports: `SpiTransport` (``spidev`` on the Pi, imported only when used) and
`SocketTransport` (the simulator's Unix datagram socket, one datagram per
exchange). Sensor 0/1 = left/right encoder, actuator 0/1 = left/right PWM.
"""

from __future__ import annotations

import contextlib
import select
import socket
import time

from icefloe.config import RobotConfig
from icefloe.errors import BoardError
from icefloe.wire.icoboard import (
    DUTY_FULL,
    BadCrc,
    FrameError,
    Op,
    Reply,
    SequenceGap,
    Status,
    Wire,
    check_ack,
)

from .board import MSG_WARNING, Board, Say
from .control import PIController, SpeedEstimator, Unwrapper, metres_per_tick

GIVE_UP_S = 0.1
"""No valid reply for this long: the link is lost (the board's own watchdog fires at 50 ms)."""


class SpiTransport:
    """A real SPI device, e.g. /dev/spidev0.0: one `exchange` = one full-duplex transfer."""

    def __init__(self, device: str, speed_hz: int) -> None:
        try:
            import spidev  # only on the Pi: the simulator does not need it
        except ImportError:
            raise BoardError(f"{device}: the spidev package is not installed "
                             "(Raspberry Pi OS: sudo apt install python3-spidev)") from None
        name = device.rsplit("spidev", 1)[-1]
        try:
            bus, chip = (int(part) for part in name.split("."))
        except ValueError:
            raise BoardError(f"{device}: not a /dev/spidevB.C device name") from None
        self.device = device
        self._spi = spidev.SpiDev()
        try:
            self._spi.open(bus, chip)
        except OSError as exc:
            raise BoardError(f"{device}: cannot open: {exc}") from None
        self._spi.max_speed_hz = speed_hz
        self._spi.mode = 0

    def exchange(self, frame: bytes, timeout_s: float) -> bytes | None:
        # SPI is synchronous: the reply is shifted in while the frame goes out.
        try:
            return bytes(self._spi.xfer2(list(frame)))
        except OSError as exc:
            raise BoardError(f"{self.device}: SPI transfer failed: {exc}") from None

    def drain(self) -> int:
        return 0

    def close(self) -> None:
        self._spi.close()


class SocketTransport:
    """The simulator's icoBoard: a Unix datagram socket, one datagram per SPI exchange."""

    def __init__(self, path: str) -> None:
        self.path = path
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._sock.bind("")  # Linux autobind: an abstract address the board can reply to
        self._sock.setblocking(False)
        self._wait = [self._sock]
        self._buf = bytearray(512)

    def exchange(self, frame: bytes, timeout_s: float) -> bytes | None:
        """Send one frame; wait at most ``timeout_s`` for the reply (None if it did not come)."""
        try:
            self._sock.sendto(frame, self.path)
        except (FileNotFoundError, ConnectionRefusedError) as exc:
            raise BoardError(f"{self.path}: icoBoard simulator socket is gone ({exc})") from None
        except BlockingIOError:
            return None  # the simulator's queue is full: a lost exchange
        # select, not poll: poll's timeout is whole milliseconds, longer than our budget.
        if not select.select(self._wait, (), (), timeout_s)[0]:
            return None
        n = self._sock.recv_into(self._buf)
        return bytes(self._buf[:n])

    def drain(self) -> int:
        """Discard replies that came after their cycle gave up on them; returns how many."""
        count = 0
        while True:
            try:
                self._sock.recv_into(self._buf)
            except BlockingIOError:
                return count
            count += 1

    def close(self) -> None:
        self._sock.close()


class IcoBoardBoard(Board):
    """The icoBoard over SPI (or the simulator's socket), protocol v1 or v2."""

    def __init__(self, config: RobotConfig, say: Say) -> None:
        super().__init__(config, say)
        board, hw = config.board, config.hwbridge
        self.wire = Wire.for_board(board)
        self.name = f"icoboard-v{self.wire.version}"
        self.period_s = 1.0 / hw.rate_hz
        k = metres_per_tick(config.geometry)
        self._speed = (SpeedEstimator(hw.speed_window_s, k), SpeedEstimator(hw.speed_window_s, k))
        self._unwrap = (Unwrapper(), Unwrapper())
        self._pi = (PIController(hw.kp, hw.ki, DUTY_FULL), PIController(hw.kp, hw.ki, DUTY_FULL))
        self._duties = [0] * self.wire.actuators
        self._transport: SpiTransport | SocketTransport | None = None
        self._seq = 0
        self._last_ok_ns = 0
        self._last_cycle_ns = 0
        self._watchdog_seen = False
        self._sent_zero = False
        """The last frame sent was a stopped one (duty 0, controllers reset)."""

    # ------------------------------------------------------------------ link

    def _connect(self) -> SpiTransport | SocketTransport:
        board = self.config.board
        if board.backend == "hardware":
            return SpiTransport(board.spi_device, board.spi_speed_hz)
        return SocketTransport(board.sim_socket)

    def _call(self, op: Op, duties: tuple[int, ...] | list[int] = (),
              timeout_s: float = 0.05) -> Reply:
        """One exchange of ``op`` during the handshake (generous timeout); the parsed reply."""
        assert self._transport is not None
        self._transport.drain()
        self._seq = (self._seq + 1) & 0xFF
        frame = self.wire.request(op, seq=self._seq, duties=duties)
        raw = self._transport.exchange(frame, timeout_s)
        if raw is None:
            raise BoardError(f"{self._where}: no reply to {op.name}")
        try:
            return self.wire.parse_reply(op, raw)
        except FrameError as exc:
            raise BoardError(f"{self._where}: bad reply to {op.name}: {exc}") from None

    @property
    def _where(self) -> str:
        b = self.config.board
        return b.spi_device if b.backend == "hardware" else b.sim_socket

    def open(self, now_ns: int) -> None:
        self.close()
        self._transport = self._connect()
        try:
            # START checks the board is the one the config describes, RESET zeroes PWM and counters.
            start = self._call(Op.START)
            self.wire.check_start(start)
            # After a lost link, a v2 board that says it kept running (byte 0 of START shows
            # the state before it) still holds the counts of the motion we did not see: keep
            # them, or odometry loses that motion. Its PWM is at zero already (`stop_lost`'s
            # frame, or else its watchdog).
            resumed = (self.wire.version == 2 and self.exchanges > 0
                       and bool(start.head & Status.RUNNING))
            if not resumed:
                self._call(Op.RESET)
            first = self._call(Op.RECEIVE)
        except BoardError:  # BoardMismatch included: the caller decides whether to retry
            self.close()
            raise
        if not resumed:
            for unwrap in self._unwrap:
                unwrap.rebase()  # counts restart at 0 on the board; ours continue
        for speed in self._speed:
            speed.reset()
        for pi in self._pi:
            pi.reset()
        self._sent_zero = self.stop_confirmed = False
        self._take_counts(first.counts, now_ns)
        self._last_ok_ns = self._last_cycle_ns = now_ns

    def close(self) -> None:
        if self._transport is not None:
            with contextlib.suppress(Exception):
                self._transport.close()
            self._transport = None

    def stop(self) -> None:
        """EXIT: the board sets every PWM duty to 0 and stops."""
        self._last_word(Op.EXIT)

    def stop_lost(self) -> None:
        """v2: a zero-duty TRANSMIT rather than EXIT, so the board stops the wheels but keeps
        running, and the reconnect finds its counts (should this frame not arrive either, the
        board's watchdog zeroes the duty 50 ms after the last frame that did)."""
        if self.wire.version == 2:
            self._last_word(Op.TRANSMIT, [0] * self.wire.actuators)
        else:
            self.stop()

    def _last_word(self, op: Op, duties: list[int] | tuple[int, ...] = ()) -> None:
        """One frame before we let go of the link: best effort, never raises, waits 20 ms at most."""
        if self._transport is None:
            return
        with contextlib.suppress(Exception):
            self._seq = (self._seq + 1) & 0xFF
            self._transport.exchange(self.wire.request(op, seq=self._seq, duties=duties), 0.02)

    # ------------------------------------------------------------------ the cycle

    def cycle(self, now_ns: int, left: float, right: float, stopped: bool, until_ns: int = 0) -> None:
        transport = self._transport
        if transport is None:
            raise BoardError(f"{self._where}: not connected")
        dt = (now_ns - self._last_cycle_ns) * 1e-9
        self._last_cycle_ns = now_ns
        duties = self._duties
        if stopped:
            # Zero, not "control to zero": a stopped robot must not creep on the integrator.
            self._pi[0].reset()
            self._pi[1].reset()
            duties[0] = duties[1] = 0
        else:
            self.stop_confirmed = False
            duties[0] = round(self._pi[0].step(left, self.speed_left, dt))
            duties[1] = round(self._pi[1].step(right, self.speed_right, dt))
        self.duty_left, self.duty_right = duties[0] / DUTY_FULL, duties[1] / DUTY_FULL
        self.late += transport.drain()
        previous_seq, previous_zero = self._seq, self._sent_zero
        self._seq = (self._seq + 1) & 0xFF
        self._sent_zero = stopped
        frame = self.wire.request(Op.TRANSMIT, seq=self._seq, duties=duties)
        # Wait for the reply for at most half a period, so the cycle keeps its deadline.
        wait = 0.5 * self.period_s
        if until_ns:
            wait = min(wait, max(0.0, (until_ns - self.clock()) * 1e-9))
        raw = transport.exchange(frame, wait)
        if raw is None:
            if not until_ns:  # a reply cut short on purpose arrives late, and is drained then
                self.timeouts += 1
        else:
            self._reply(raw, previous_seq, self.clock(), previous_zero and stopped)
        if now_ns - self._last_ok_ns > GIVE_UP_S * 1e9:
            raise BoardError(f"{self._where}: no valid reply for {GIVE_UP_S * 1e3:.0f} ms")

    def _reply(self, raw: bytes, previous_seq: int, now_ns: int, confirms: bool = False) -> None:
        """A reply to the frame after ``previous_seq``; ``confirms``: that frame, and this one,
        were stopped ones, so a reply showing the board took it confirms the stop."""
        try:
            reply = self.wire.parse_reply(Op.TRANSMIT, raw)
        except BadCrc:
            self.crc_errors += 1
            return
        except FrameError:
            self.garbage_bytes += len(raw)
            return
        if self.wire.version == 2:
            if not reply.head & Status.RUNNING:
                raise BoardError(f"{self._where}: the board is not running (reset or power loss?)")
            if reply.head & Status.REJECTED:
                self.board_errors += 1
            if reply.head & Status.WATCHDOG:
                if not self._watchdog_seen:
                    self.watchdog += 1
                    self.say(MSG_WARNING, "icoBoard watchdog had stopped the wheels "
                                          "(no valid frame for 50 ms); driving again")
                self._watchdog_seen = True
            else:
                self._watchdog_seen = False
            try:
                check_ack(previous_seq, reply)
            except SequenceGap:
                self.lost += 1  # our previous frame never arrived; this reply is still good
            else:
                # v2: the board acknowledges the zero-duty frame it received and applied.
                self.stop_confirmed = self.stop_confirmed or confirms
        elif reply.head != Op.TRANSMIT:
            self.garbage_bytes += len(raw)  # v1 has no CRC: a wrong byte 0 is all we can see
            return
        else:
            # v1 acknowledges nothing: that the board, running, answered the exchange after
            # the zero-duty frame is all the evidence there is.
            self.stop_confirmed = self.stop_confirmed or confirms
        self._take_counts(reply.counts, now_ns)
        self._last_ok_ns = now_ns
        self.exchanges += 1

    def _take_counts(self, counts: tuple[int, ...], now_ns: int) -> None:
        if len(counts) < 2:
            return
        self.ticks_left = self._unwrap[0].update(counts[0])
        self.ticks_right = self._unwrap[1].update(counts[1])
        self.sample_ns = now_ns
        self.stamp = time.time_ns()
        self.speed_left = self._speed[0].update(now_ns, self.ticks_left)
        self.speed_right = self._speed[1].update(now_ns, self.ticks_right)

