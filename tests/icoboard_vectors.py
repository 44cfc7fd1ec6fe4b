"""Protocol v2 test vectors shared by every layer: the Python board model, hwbridge's host side, the gateware.

One scenario is a sequence of steps, run from power-up at t = 0 with both
encoders at 0. The frames are literal bytes (made once with the Python model,
then checked by hand against `icefloe.wire.icoboard`'s documentation), so each
layer is held to the same bytes, not to another layer's code:

* ``Send(request, reply)``: one exchange; ``reply`` is the board's bytes (hex),
  or ``Head(status)`` where only byte 0 is fixed (a frame of the wrong length:
  the board cannot know the length in advance, so the rest is its own business).
* ``Move(left, right)``: the wheels turn to these encoder counts (unbounded;
  the wire wraps them at 16 bits). The board must see them before the next frame.
* ``Wait(ms)``: time passes.
* ``Duty(left, right)``: the duty the motors get now (fractions, within 0.002).
* ``Trips(n)``: watchdog trips since power-up.

Runners: tests/test_sim_icoboard.py (the Python model), tests/test_hwbridge_icoboard_host.py
(hwbridge's board code, replaying the replies), tests/test_gateware_protocol.py (the
gateware in Amaranth's simulator, bit by bit through its SPI pins) and
tests/test_gateware_cxxsim.py (the same gateware compiled, at 100 MHz).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Head:
    """A reply of which only byte 0 (the status) is fixed."""

    status: int


@dataclass(frozen=True)
class Send:
    request_hex: str
    reply_hex: str | Head

    @property
    def request(self) -> bytes:
        return bytes.fromhex(self.request_hex)

    @property
    def reply(self) -> bytes | None:
        """The whole reply, or None when only its status byte is fixed."""
        return None if isinstance(self.reply_hex, Head) else bytes.fromhex(self.reply_hex)

    @property
    def status(self) -> int:
        return self.reply_hex.status if isinstance(self.reply_hex, Head) else self.reply[0]


@dataclass(frozen=True)
class Move:
    left: int
    right: int


@dataclass(frozen=True)
class Wait:
    ms: int


@dataclass(frozen=True)
class Duty:
    left: float
    right: float


@dataclass(frozen=True)
class Trips:
    count: int


Step = Send | Move | Wait | Duty | Trips

DUTY_TOLERANCE = 0.002
"""Duty checks hold within this (the gateware's PWM has 5000 steps per period at 100 MHz)."""

SCENARIOS: dict[str, tuple[Step, ...]] = {
    # Every opcode once, same-period sampling (counts moved just before a frame come back in
    # it), 16-bit wrap of negative counts, EXIT and RESET, the descriptor and its hash.
    "run": (
        Send("01 01 00 00 00 00 00 00 00 ac", "00 00 02 02 02 f6 c3 e0 37 7f"),
        Send("05 02 25", "01 01 81"),
        Move(5, -3),
        Send("02 03 00 00 00 00 ef", "01 02 00 05 ff fd 2c"),
        Send("03 04 40 00 e0 00 a7", "01 03 00 05 ff fd 81"),
        Wait(2),
        Duty(0.5, -0.25),
        Move(1000, -1000),
        Send("03 05 c0 00 20 00 58", "01 04 03 e8 fc 18 27"),
        Wait(2),
        Duty(-0.5, 0.25),
        Move(1003, -1004),
        Send("02 06 00 00 00 00 a8", "01 05 03 eb fc 14 73"),
        Send("00 07 8a", "01 06 4c"),
        Send("04 08 c5", "01 07 63"),
        Wait(2),
        Duty(0.0, 0.0),
        Send("01 09 00 00 00 00 00 00 00 fd", "00 08 02 02 02 f6 c3 e0 37 2e"),
        Send("05 0a 72", "01 09 d6"),
        Send("02 0b 00 00 00 00 14", "01 0a 00 00 00 00 45"),
    ),
    # A corrupt frame (CRC) is not used; the next reply says REJECTED and acks the frame before it.
    "lost_frames": (
        Send("01 01 00 00 00 00 00 00 00 ac", "00 00 02 02 02 f6 c3 e0 37 7f"),
        Send("03 02 40 00 40 00 75", "01 01 00 00 00 00 66"),
        Send("03 03 40 00 c0 00 1e", "01 02 00 00 00 00 be"),
        Send("02 04 00 00 00 00 dd", "05 02 00 00 00 00 c1"),
        Send("02 05 00 00 00 00 70", "01 04 00 00 00 00 21"),
        Wait(2),
        Duty(0.5, 0.5),
        Send("03 06 00 00 00 00 fd", "01 05 00 00 00 00 8c"),
        Send("02 07 00 00 00 00 05", "05 05 00 00 00 00 f3"),
        Wait(2),
        Duty(0.5, 0.5),
    ),
    # Data before START, an unknown opcode, frames a byte short and a byte long: rejected, nothing moves.
    "bad_frames": (
        Send("03 01 40 00 40 00 ad", "00 00 00 00 00 00 9f"),
        Send("02 02 00 00 00 00 42", "04 00 00 00 00 00 e0"),
        Send("09 03 5a", "04 00 92"),
        Send("01 04 00 00 00 00 00 00 00 77", "04 00 02 02 02 f6 c3 e0 37 db"),
        Send("03 05 40 00 40 00", Head(1)),
        Send("03 06 40 00 40 00 9f 00", Head(5)),
        Send("02 07 00 00 00 00 05", "05 04 00 00 00 00 5e"),
        Wait(2),
        Duty(0.0, 0.0),
    ),
    # 50 ms without a valid frame stops the wheels once; TRANSMIT drives again; EMPTY keeps it alive.
    "watchdog": (
        Send("01 01 00 00 00 00 00 00 00 ac", "00 00 02 02 02 f6 c3 e0 37 7f"),
        Send("03 02 40 00 c0 00 72", "01 01 00 00 00 00 66"),
        Wait(49),
        Duty(0.5, -0.5),
        Trips(0),
        Wait(2),
        Duty(0.0, 0.0),
        Trips(1),
        Send("02 03 00 00 00 00 ef", "03 02 00 00 00 00 16"),
        Send("03 04 40 00 40 00 ea", "03 03 00 00 00 00 bb"),
        Send("02 05 00 00 00 00 70", "01 04 00 00 00 00 21"),
        Wait(2),
        Duty(0.5, 0.5),
        Wait(30),
        Send("00 06 a5", "01 05 3d"),
        Wait(30),
        Send("00 07 8a", "01 06 4c"),
        Wait(30),
        Duty(0.5, 0.5),
        Trips(1),
    ),
}
