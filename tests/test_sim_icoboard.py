"""The simulated icoBoard: whole v1 and v2 runs through its datagram socket, on a stepped clock.

The test is the simulator's clock here: it steps the real `World` and ticks the
board one millisecond at a time, so every timing (the one-period-late v1 data,
the 50 ms watchdog) is checked exactly.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest
from icoboard_vectors import DUTY_TOLERANCE, SCENARIOS, Duty, Move, Send, Trips, Wait

from icefloe.config import Board, Geometry
from icefloe.errors import BoardMismatch
from icefloe.sim.gpio import ACK, BUTTON, REQUEST, GpioLines
from icefloe.sim.icoboard import TICK_FRAMES, IcoBoardModel, IcoBoardSim
from icefloe.sim.world import World
from icefloe.wire.icoboard import (
    BadCrc,
    Descriptor,
    Op,
    Status,
    Wire,
    check_ack,
    duty_to_raw,
)

HALF = duty_to_raw(0.5)


class Bench:
    """A World, a board behind its socket, a host socket, and a millisecond clock."""

    def __init__(self, tmp: Path, protocol: int) -> None:
        board = Board(kind="icoboard", protocol=protocol, sim_socket=str(tmp / "run" / "ico.sock"))
        self.world = World(Geometry(), seed=1)
        self.sim = IcoBoardSim(self.world, board)
        self.wire = Wire.for_board(board)
        self.host = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.host.bind("")  # autobind an abstract address, so replies can reach us
        self.host.settimeout(2.0)
        self.host.connect(board.sim_socket)
        self.ms = 0
        self.seq = 0

    @property
    def now(self) -> float:
        return self.ms / 1000

    def run(self, ms: int) -> None:
        for _ in range(ms):
            self.ms += 1
            self.world.step(0.001)
            self.sim.tick(self.now)

    def exchange(self, frame: bytes) -> bytes:
        self.host.send(frame)
        reply = self.host.recv(4096)
        assert len(reply) == len(frame), "full duplex: the reply is as long as the request"
        return reply

    def send(self, op: Op, duties: tuple[int, int] = (0, 0)) -> bytes:
        self.seq += 1
        return self.exchange(self.wire.request(op, seq=self.seq, duties=duties))

    def close(self) -> None:
        self.host.close()
        self.sim.close()


@pytest.fixture
def bench(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[Bench]:
    b = Bench(tmp_path, request.param)
    yield b
    b.close()


@pytest.mark.parametrize("bench", [1], indirect=True)
def test_v1_run_start_receive_transmit_exit(bench: Bench) -> None:
    wire = bench.wire
    start = wire.parse_reply(Op.START, bench.send(Op.START))
    assert start.head == 2  # M
    wire.check_start(start)
    bench.run(5)
    assert wire.parse_reply(Op.RECEIVE, bench.send(Op.RECEIVE)).counts == (0, 0)
    sampled = []
    for _ in range(40):
        sampled.append(bench.world.counts())
        reply = wire.parse_reply(Op.TRANSMIT, bench.send(Op.TRANSMIT, (HALF, HALF)))
        assert reply.head == Op.TRANSMIT
        if len(sampled) >= 2:
            # one period late: this reply carries what the board sampled one exchange ago
            assert reply.counts == tuple(c & 0xFFFF for c in sampled[-2])
        bench.run(10)
    assert bench.world.duty == pytest.approx((0.5, 0.5), abs=1e-4)
    assert sampled[-1][0] > 100  # the wheels turned
    assert bench.send(Op.EXIT) == bytes([Op.TRANSMIT])  # EXIT's reply is cut to one byte
    assert bench.world.duty == (0.0, 0.0)
    assert bench.send(Op.START) == b"\x02"  # stopped again: byte 0 is M


@pytest.mark.parametrize("bench", [1], indirect=True)
def test_v1_has_no_checksum_and_no_watchdog(bench: Bench) -> None:
    bench.send(Op.START)
    corrupt = bytearray(bench.wire.request(Op.TRANSMIT, duties=(HALF, HALF)))
    corrupt[1] ^= 0x80  # a flipped bit on MOSI turns +50 % into -50 %: v1 cannot tell
    bench.exchange(bytes(corrupt))
    assert bench.world.duty[0] < -0.49
    bench.run(500)  # the host went silent; the wheels run on
    assert bench.world.duty[0] < -0.49
    assert bench.sim.model.counters.watchdog_trips == 0


@pytest.mark.parametrize("bench", [2], indirect=True)
def test_v2_run_samples_now_and_acks(bench: Bench) -> None:
    wire = bench.wire
    start = wire.parse_reply(Op.START, bench.send(Op.START))
    assert start.head == 0  # not running yet when byte 0 left
    wire.check_start(start)
    first = wire.parse_reply(Op.RECEIVE, bench.send(Op.RECEIVE))
    assert first.head == Status.RUNNING and first.counts == (0, 0)
    check_ack(bench.seq - 1, first)
    for _ in range(30):
        bench.run(10)
        now = bench.world.counts()
        reply = wire.parse_reply(Op.TRANSMIT, bench.send(Op.TRANSMIT, (HALF, -HALF)))
        check_ack(bench.seq - 1, reply)
        assert reply.counts == (now[0] & 0xFFFF, now[1] & 0xFFFF)  # sampled just before
    assert bench.world.counts()[0] > 100 and bench.world.counts()[1] < -100
    bench.send(Op.EXIT)
    assert bench.world.duty == (0.0, 0.0) and not bench.sim.model.running
    assert bench.sim.model.counters.bad_frames == 0
    assert bench.sim.model.counters.seq_gaps == 0


@pytest.mark.parametrize("bench", [2], indirect=True)
def test_v2_descriptor_mismatch_is_refused(bench: Bench) -> None:
    bench.sim.model.forced_descriptor = Descriptor.of(3, 2)
    start = bench.wire.parse_reply(Op.START, bench.send(Op.START))
    with pytest.raises(BoardMismatch, match=r"sensors M = 3 \(config says 2\)"):
        bench.wire.check_start(start)


@pytest.mark.parametrize("bench", [2], indirect=True)
def test_v2_watchdog_stops_the_wheels_after_50_ms(bench: Bench) -> None:
    bench.send(Op.START)
    bench.send(Op.TRANSMIT, (HALF, HALF))
    bench.run(49)
    assert bench.world.duty == pytest.approx((0.5, 0.5), abs=1e-4)  # 49 ms: still driving
    bench.run(1)
    assert bench.world.duty == (0.0, 0.0)  # 50 ms without a valid frame
    assert bench.sim.model.counters.watchdog_trips == 1
    reply = bench.wire.parse_reply(Op.RECEIVE, bench.send(Op.RECEIVE))
    assert reply.head & Status.WATCHDOG
    bench.send(Op.TRANSMIT, (HALF, HALF))  # the host is back: driving again, flag cleared
    assert bench.world.duty[0] > 0.49
    assert not bench.wire.parse_reply(Op.RECEIVE, bench.send(Op.RECEIVE)).head & Status.WATCHDOG


@pytest.mark.parametrize("bench", [2], indirect=True)
def test_v2_valid_frames_feed_the_watchdog(bench: Bench) -> None:
    bench.send(Op.START)
    bench.send(Op.TRANSMIT, (HALF, HALF))
    for _ in range(10):
        bench.run(40)
        bench.send(Op.EMPTY)  # a keep-alive every 40 ms
    assert bench.world.duty[0] > 0.49 and bench.sim.model.counters.watchdog_trips == 0


@pytest.mark.parametrize("bench", [2], indirect=True)
def test_v2_a_frame_waiting_in_the_socket_is_taken_before_the_watchdog_looks(bench: Bench) -> None:
    """The simulator's process was descheduled: the host's EXIT (sent in time) waits in the
    socket while the clock catches up 60 ms. The clock answers it first; the watchdog stays quiet."""
    bench.send(Op.START)
    bench.send(Op.TRANSMIT, (HALF, HALF))
    with bench.sim.lock:  # the socket thread cannot answer: only the clock can
        bench.seq += 1
        bench.host.send(bench.wire.request(Op.EXIT, seq=bench.seq))
        bench.run(60)
    assert bench.host.recv(4096)[0] & Status.RUNNING  # the reply, sent by the clock's first tick
    assert bench.sim.model.last_frame[0] == Op.EXIT
    assert bench.sim.model.counters.watchdog_trips == 0
    assert bench.world.duty == (0.0, 0.0)


@pytest.mark.parametrize("bench", [2], indirect=True)
def test_a_host_flooding_the_socket_does_not_hold_the_clock(bench: Bench) -> None:
    """Another process sends frames as fast as it can: the clock answers a bounded number in
    each millisecond, and steps on. (Without the bound, 20 ticks took 0.6 to 1.1 s here, the
    clock answering the flood; with it, 65 to 90 ms.)"""
    flood = subprocess.Popen([sys.executable, "-c", FLOOD, bench.sim.path.as_posix(),
                              bench.wire.request(Op.EMPTY).hex()])
    try:
        while bench.sim.model.counters.frames < 1000:  # the flood is on
            assert flood.poll() is None, "the flooding process died"
            time.sleep(0.01)
        model, clock = bench.sim.model, threading.current_thread()  # this test is the clock
        exchange, by_clock = model.exchange, [0]

        def counted(frame: bytes, now: float) -> bytes:
            by_clock[0] += threading.current_thread() is clock
            return exchange(frame, now)

        model.exchange = counted
        per_tick = []
        for _ in range(20):
            by_clock[0] = 0
            bench.run(1)
            per_tick.append(by_clock[0])
        model.exchange = exchange
        assert max(per_tick) <= TICK_FRAMES, per_tick
    finally:
        flood.kill()
        flood.wait()
    assert bench.send(Op.RECEIVE)  # and the board still answers


FLOOD = """
import socket, sys
sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
sock.connect(sys.argv[1])
frame = bytes.fromhex(sys.argv[2])
while True:
    try:
        sock.send(frame)
    except BlockingIOError:
        pass
"""


@pytest.mark.parametrize("bench", [2], indirect=True)
def test_v2_a_delayed_reply_holds_back_the_frames_after_it(bench: Bench) -> None:
    bench.send(Op.START)
    bench.sim.delay_replies(0.3, count=1)
    bench.seq += 1
    bench.host.send(bench.wire.request(Op.TRANSMIT, seq=bench.seq, duties=(HALF, HALF)))
    bench.seq += 1
    bench.host.send(bench.wire.request(Op.TRANSMIT, seq=bench.seq, duties=(-HALF, -HALF)))
    bench.run(5)  # the clock must not take the second frame past the held-back first
    assert bench.world.duty[0] > -0.49  # the first taken, or (a busy machine) neither yet
    first, second = (bench.wire.parse_reply(Op.TRANSMIT, bench.host.recv(4096)) for _ in range(2))
    assert (first.ack, second.ack) == (bench.seq - 2, bench.seq - 1)  # in order, each acking the one before
    assert bench.world.duty[0] < -0.49


@pytest.mark.parametrize("bench", [2], indirect=True)
def test_v2_corrupt_frames_are_counted_not_used(bench: Bench) -> None:
    model = bench.sim.model
    bench.send(Op.START)
    bench.send(Op.TRANSMIT, (HALF, HALF))
    model.corrupt(requests=5)
    for _ in range(5):
        bench.send(Op.TRANSMIT, (-HALF, -HALF))
    assert model.counters.bad_frames == 5
    assert bench.world.duty[0] > 0.49  # none of the corrupt frames was applied
    reply = bench.wire.parse_reply(Op.RECEIVE, bench.send(Op.RECEIVE))
    assert reply.head & Status.REJECTED  # the host hears of the last one
    with pytest.raises(Exception, match="acknowledged seq"):
        check_ack(bench.seq - 1, reply)  # ... and sees its frame was not taken
    bench.send(Op.RECEIVE)
    assert model.counters.seq_gaps == 1  # the first valid frame after the 5 lost ones
    model.corrupt(replies=1)
    with pytest.raises(BadCrc):
        bench.wire.parse_reply(Op.RECEIVE, bench.send(Op.RECEIVE))
    assert model.last_frame[0] == Op.RECEIVE


@pytest.mark.parametrize("bench", [2], indirect=True)
def test_bad_lengths_and_opcodes_are_counted_and_the_board_keeps_answering(bench: Bench) -> None:
    model = bench.sim.model
    assert bench.exchange(b"\x03\x01\x02") == bytes(3)  # TRANSMIT before START, too short
    assert bench.exchange(b"\x09" * 7)[0] == Status.REJECTED  # says the last one was bad
    assert bench.exchange(bench.wire.request(Op.RECEIVE, seq=1)) != b""  # before START
    assert model.counters.bad_length == 1 and model.counters.bad_opcode == 2
    start = bench.wire.parse_reply(Op.START, bench.send(Op.START))
    bench.wire.check_start(start)


@pytest.mark.parametrize("protocol", [1, 2])
def test_reset_zeroes_counters_and_pwm(protocol: int) -> None:
    world = World(Geometry(), seed=3)
    wire = Wire(protocol)
    model = IcoBoardModel(world, wire)
    model.exchange(wire.request(Op.START, seq=0), 0.0)
    model.exchange(wire.request(Op.TRANSMIT, seq=1, duties=[HALF, HALF]), 0.0)
    for _ in range(300):
        world.step(0.001)
    assert model.counts()[0] > 50
    model.exchange(wire.request(Op.RESET, seq=2), 0.3)
    assert model.counts() == (0, 0) and world.duty == (0.0, 0.0) and model.running


def test_gpio_lines_hold_release_and_report_changes() -> None:
    changes: list[tuple[int, int]] = []
    board_pb5 = {"low": False}
    gpio = GpioLines(request_source=lambda: board_pb5["low"],
                     on_change=lambda line, level: changes.append((line, level)))
    assert gpio.levels() == {BUTTON: 1, REQUEST: 1, ACK: 0}
    gpio.tick(1.0)
    gpio.hold(0.5)
    assert gpio.button == 0
    gpio.tick(1.499)
    assert gpio.button == 0
    gpio.tick(1.5)
    assert gpio.button == 1 and gpio.presses == 1
    board_pb5["low"] = True
    gpio.tick(1.501)
    assert gpio.request == 0
    gpio.set(ACK, 1)
    assert not gpio.ack_fell
    gpio.set(ACK, 0)
    assert gpio.ack_fell
    assert changes == [(BUTTON, 0), (BUTTON, 1), (REQUEST, 0), (ACK, 1), (ACK, 0)]
    with pytest.raises(ValueError, match="GPIO7 is not simulated"):
        gpio.set(7, 0)
    with pytest.raises(ValueError, match="level must be 0 or 1"):
        gpio.set(ACK, 2)


def test_board_config_is_the_wire() -> None:
    board = msgspec.structs.replace(Board(), protocol=1, sensors=3, actuators=1)
    assert Wire.for_board(board) == Wire(1, 3, 1)


class _Wheels:
    """The world as the shared vectors move it: encoder counts set by hand, duty recorded."""

    def __init__(self) -> None:
        self.position = (0, 0)
        self.duty = (0.0, 0.0)

    def set_duty(self, left: float, right: float) -> None:
        self.duty = (left, right)

    def counts(self) -> tuple[int, int]:
        return self.position


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_the_python_model_meets_the_shared_vectors(name: str) -> None:
    wheels = _Wheels()
    model = IcoBoardModel(wheels, Wire(2))
    ms = 0
    for step in SCENARIOS[name]:
        match step:
            case Send():
                reply = model.exchange(step.request, ms / 1000)
                assert reply[0] == step.status, step
                assert step.reply is None or reply == step.reply, step
            case Move():
                wheels.position = (step.left, step.right)
            case Wait():
                for _ in range(step.ms):
                    ms += 1
                    model.tick(ms / 1000)
            case Duty():
                assert model.duty == pytest.approx((step.left, step.right), abs=DUTY_TOLERANCE), step
            case Trips():
                assert model.counters.watchdog_trips == step.count
