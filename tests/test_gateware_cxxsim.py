"""The gateware compiled (CXXRTL + g++) at the board's 100 MHz: vectors, SPI clock range, delays.

The same design as tests/test_gateware_protocol.py, at its real clock: every
frame still goes bit by bit through the SPI pins, only in C++ instead of Python.
The figures docs/gateware.md quotes are measured here (run with ``-s`` to see them).
"""

from __future__ import annotations

import random

import pytest
from icoboard_vectors import DUTY_TOLERANCE, SCENARIOS, Duty, Move, Send, Trips, Wait

from icefloe.gateware.cxxsim import CompiledBoard
from icefloe.wire.icoboard import Op, Wire, duty_to_raw

CLK_HZ = 100e6
SETUP = 1
"""CIPO is sampled one cycle (10 ns) before SCK rises: pad delays and the Pi's setup time."""
FASTEST_HALF = 3
"""SCK half period, in 10 ns cycles, of the fastest SPI clock that works (measured below)."""

wire = Wire(2)

pytestmark = pytest.mark.timeout(600)  # the first compile on a fresh machine also compiles Yosys (WebAssembly)


@pytest.fixture(scope="module")
def board_type():
    boards = []

    def make() -> CompiledBoard:
        boards.append(CompiledBoard(clk_hz=CLK_HZ))
        return boards[-1]

    yield make
    for board in boards:
        board.close()


def _run_vectors(board: CompiledBoard, steps, half: int) -> None:
    trips = 0
    duty = None
    ms = board.cycles(1e-3)
    position = [0, 0]
    for step in steps:
        match step:
            case Send():
                reply = board.exchange(step.request, half=half, setup=SETUP)
                assert reply[0] == step.status, (step, reply.hex(" "))
                assert step.reply is None or reply == step.reply, (step, reply.hex(" "))
            case Move():
                steps_to_go = max(abs(step.left - position[0]), abs(step.right - position[1]))
                position = [step.left, step.right]
                board.set_encoders(position)
                board.step(max(ms, steps_to_go * (board.core.filter_cycles + 4)))
            case Wait():
                board.step((step.ms - 1) * ms)
                trips += board.read().trips
                board.step(ms)                       # the motors' view: the mean over the last ms
                stats = board.read()
                trips += stats.trips
                duty = stats.duty
            case Duty():
                assert duty == pytest.approx((step.left, step.right), abs=DUTY_TOLERANCE), step
            case Trips():
                assert trips == step.count, step


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_the_compiled_gateware_meets_the_shared_vectors_at_100_mhz(board_type, name: str) -> None:
    _run_vectors(board_type(), SCENARIOS[name], half=5)  # SCK 10 MHz


def test_spi_clock_range(board_type) -> None:
    """Every SCK from 100 kHz up to 100 MHz / (2 * FASTEST_HALF) works; one step faster does not."""
    works = {}
    for half in (FASTEST_HALF - 1, FASTEST_HALF, 4, 5, 8, 50, 500):
        try:
            _run_vectors(board_type(), SCENARIOS["run"], half=half)
            works[half] = True
        except AssertionError:
            works[half] = False
    print(f"\nSPI: SCK half period (cycles of 10 ns) -> works: {works}; "
          f"fastest {CLK_HZ / (2 * FASTEST_HALF) / 1e6:.1f} MHz")
    assert not works[FASTEST_HALF - 1]
    assert all(ok for half, ok in works.items() if half >= FASTEST_HALF)


def test_a_count_wraps_at_16_bits_and_comes_back(board_type) -> None:
    board = board_type()
    board.exchange(wire.request(Op.START, seq=1), half=5)
    board.set_encoders([70_000, -70_000])
    board.step(70_000 * 110)          # one step every 1.1 us: the 1 us glitch filter passes each
    reply = wire.parse_reply(Op.RECEIVE, board.exchange(wire.request(Op.RECEIVE, seq=2), half=5))
    assert reply.counts == (70_000 & 0xFFFF, -70_000 & 0xFFFF)


def test_sample_to_action_delay_at_1_khz(board_type) -> None:
    """Encoder sample (CS falls) -> the PWM pulse whose duty was computed from it, host at 1 kHz."""
    board = board_type()
    period = board.cycles(1e-3)
    half = 50                                         # SCK 1 MHz, hwbridge's default spi_speed_hz
    board.exchange(wire.request(Op.START, seq=1), half=half)
    board.step(period)
    # Period k: the host reads the counts; the CS falling edge of this exchange is the sample.
    board.exchange(wire.request(Op.RECEIVE, seq=2), half=half)
    sampled = board.last_cs_fall
    board.step(period - (board.read().total_cycles - sampled))
    # Period k + 1: the duty worked out from that sample goes out; the PWM pin acts on it.
    board.exchange(wire.request(Op.TRANSMIT, seq=3, duties=[duty_to_raw(0.5), 0]), half=half)
    waited = board.until_pwm(0, 1, board.cycles(1e-3))
    delay = (board.read().total_cycles - sampled) / CLK_HZ
    print(f"\nsample-to-action: {delay * 1e6:.1f} us at 1 kHz with SCK 1 MHz "
          f"(period 1000 us + exchange + wait for the PWM period: {waited / CLK_HZ * 1e6:.1f} us)")
    assert delay < 1e-3 + 0.2e-3


class _Still:
    """Wheels that do not move (the fuzz test is about frames)."""

    def set_duty(self, left: float, right: float) -> None:
        pass

    def counts(self) -> tuple[int, int]:
        return (0, 0)


def _hostile_frames(rng: random.Random, count: int):
    """Valid frames of every opcode, the same with one bit flipped, cut short or too long, and garbage."""
    seq = 0
    for _ in range(count):
        seq = (seq + 1) & 0xFF
        op = rng.choice(list(Op))
        duties = [rng.randrange(-32768, 32768) for _ in range(2)]
        frame = bytearray(wire.request(op, seq=seq, duties=duties if op == Op.TRANSMIT else ()))
        kind = rng.random()
        if kind < 0.2:
            frame[rng.randrange(len(frame))] ^= 1 << rng.randrange(8)
        elif kind < 0.3:
            frame = frame[: rng.randrange(len(frame))]
        elif kind < 0.4:
            frame += bytes(rng.randrange(1, 4))
        elif kind < 0.5:
            frame = bytearray(rng.randbytes(rng.randrange(0, 12)))
        yield bytes(frame)


def test_hostile_frames_get_the_same_answers_from_the_gateware_and_the_python_model(board_type) -> None:
    """1000 frames, a third of them broken: the gateware and the model agree on every reply."""
    from icefloe.sim.icoboard import IcoBoardModel

    board, model = board_type(), IcoBoardModel(_Still(), wire)
    rng = random.Random(20)
    for n, frame in enumerate(_hostile_frames(rng, 1000)):
        got, want = board.exchange(frame, half=5), model.exchange(frame, 0.0)
        if frame and frame[0] <= max(Op) and len(frame) == wire.length(Op(frame[0])):
            assert got == want, (n, frame.hex(" "), got.hex(" "), want.hex(" "))
        elif frame:
            assert got[:1] == want[:1], (n, frame.hex(" "), got.hex(" "), want.hex(" "))
    assert model.counters.bad_frames > 300 and model.counters.frames - model.counters.bad_frames > 300
    # Still answering, and the same duty applied: after the flood, and after one more good TRANSMIT.
    for frame in (None, wire.request(Op.START, seq=1),
                  wire.request(Op.TRANSMIT, seq=2, duties=[duty_to_raw(0.3), duty_to_raw(-0.6)])):
        if frame:
            assert board.exchange(frame, half=5) == model.exchange(frame, 0.0)
        board.step(board.cycles(0.1e-3))  # the last duty has been taken (at most one 50 us PWM period)
        board.read()
        board.step(board.cycles(1e-3))
        assert board.read().duty == pytest.approx(model.duty, abs=DUTY_TOLERANCE)
    assert model.duty == pytest.approx((0.3, -0.6), abs=1e-4)
