"""Stopped means zero duty, controller cleared; a stop is confirmed only when it is so.

The backends run against the board models in simulated time, one millisecond at a
time: the PenguinPi backend over a real pseudo-terminal (pyserial) to the firmware
model, the icoBoard backend straight into the icoBoard model. Then the cycle and the
bus side's wait for a confirmation, on real shared memory.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque

import msgspec
import pytest
from test_hwbridge_backends import BoardEnd

from icefloe.config import Geometry, RobotConfig
from icefloe.errors import NotConfirmed
from icefloe.ordering import Origin
from icefloe.schemas import messages as m
from icefloe.services.hwbridge.board import Board
from icefloe.services.hwbridge.bridge import Bridge
from icefloe.services.hwbridge.icoboard import IcoBoardBoard
from icefloe.services.hwbridge.penguinpi import REPLY_TIMEOUT_NS, PenguinPiBoard
from icefloe.services.hwbridge.rt import Cycle
from icefloe.services.hwbridge.shm import STATE_FIELDS, Shared
from icefloe.sim.icoboard import IcoBoardModel
from icefloe.sim.penguinpi_firmware import PenguinPiFirmware
from icefloe.sim.world import World
from icefloe.wire import penguinpi as ppi
from icefloe.wire.icoboard import Wire

MS = 1_000_000


class Firmware:
    """The PenguinPi firmware model at the board's end of a pseudo-terminal, in simulated time.

    `step` is one millisecond: the host's cycle, the host's bytes into the firmware, the
    world and the firmware's 1 ms timer. Replies can be held back (`delay`), and what the
    host sends can be changed on its way (`tamper`).
    """

    def __init__(self, tmp_path) -> None:
        self.end = BoardEnd(tmp_path)
        self.world = World(Geometry(), seed=1)
        self.fw = PenguinPiFirmware(self.world, transmit=self._transmit)
        self.ms = 0
        self._held: deque[tuple[int, bytes]] = deque()
        self.delay_ms, self.delays = 0, 0
        self.delay_only = b""
        """Delay only replies that start with these bytes (b"": any)."""
        self.tamper = lambda data: data
        config = msgspec.convert({"board": {"serial_port": str(self.end.path)}}, RobotConfig)
        self.said: list[str] = []
        self.board = PenguinPiBoard(config, lambda kind, text: self.said.append(text))
        self.board.open(0)

    def _transmit(self, data: bytes) -> None:
        due = self.ms
        if self.delays and data.startswith(self.delay_only):
            self.delays -= 1
            due += self.delay_ms
        if self._held:  # the line is FIFO: nothing overtakes a held reply
            due = max(due, self._held[-1][0])
        self._held.append((due, data))

    def step(self, left: float = 0.0, right: float = 0.0, stopped: bool = False, host: bool = True) -> None:
        """``host``: the host's cycle runs in this millisecond (False: a resting cycle's sleep)."""
        while self._held and self._held[0][0] <= self.ms:
            self.end.write(self._held.popleft()[1])
        if host:
            self.board.cycle(self.ms * MS, left, right, stopped)
        data = self.end.read()
        if data:
            self.fw.receive(self.tamper(data), self.ms * 1e-3)
        self.ms += 1
        self.world.step(0.001)
        self.fw.tick(self.ms * 1e-3)

    def run(self, ms: int, left: float = 0.0, right: float = 0.0, stopped: bool = False) -> None:
        for _ in range(ms):
            self.step(left, right, stopped)

    @property
    def duty(self) -> tuple[float, float]:
        return self.world.duty

    @property
    def integrators(self) -> tuple[int, int]:
        return self.fw.left.integral, self.fw.right.integral

    def close(self) -> None:
        self.board.close()
        self.end.close()


@pytest.fixture
def firmware(tmp_path):
    f = Firmware(tmp_path)
    yield f
    f.close()


def test_firmware_model_keeps_its_integrator_after_a_plain_stop(firmware: Firmware) -> None:
    """What the real firmware does (and why hwbridge sets the integral gain): demand 0 alone
    leaves the PWM registers energised, and the robot creeps."""
    fw = firmware.fw
    fw.receive(ppi.encode_frame(ppi.Address.AD_MULTI, ppi.MultiOp.MULTI_SET_VEL, ppi.pack_multi_set(40, 40)), 0)
    for ms in range(1, 1001):
        firmware.world.step(0.001)
        fw.tick(ms * 1e-3)
    fw.receive(ppi.encode_frame(ppi.Address.AD_MULTI, ppi.MultiOp.MULTI_ALL_STOP), 1.0)
    for ms in range(1001, 3001):
        firmware.world.step(0.001)
        fw.tick(ms * 1e-3)
    # Two seconds after MULTI_ALL_STOP: the integrators are not 0, the registers not 0.
    assert fw.left.integral != 0 and fw.right.integral != 0
    assert 0 < abs(fw.left.command * 2) <= 22 and firmware.world.duty != (0.0, 0.0)


def test_penguinpi_stop_zero_duty_integrator_clear_then_confirmed(firmware: Firmware) -> None:
    board = firmware.board
    firmware.run(1000, 0.2, 0.2)                       # drive: the firmware's integrators fill
    assert board.exchanges > 150 and firmware.duty[0] > 0.1 and firmware.integrators != (0, 0)
    stop_ms = firmware.ms
    zero_ms = confirmed_ms = None
    while confirmed_ms is None:
        firmware.step(stopped=True)
        if zero_ms is None and firmware.duty == (0.0, 0.0):
            zero_ms = firmware.ms
            assert firmware.integrators == (0, 0)       # the same control step cleared them
        if board.stop_confirmed:
            confirmed_ms = firmware.ms
        assert firmware.ms - stop_ms < 100, "no confirmation"
    # Zero duty at the firmware's next 20 ms control step, confirmed after it, not before.
    assert zero_ms is not None and zero_ms - stop_ms <= 21
    assert zero_ms <= confirmed_ms <= stop_ms + 30, (stop_ms, zero_ms, confirmed_ms)
    # And it stays so: no creep, no hum (the integrator stays clear while the wheels coast).
    for _ in range(1000):
        firmware.step(stopped=True)
        assert firmware.duty == (0.0, 0.0) and firmware.integrators == (0, 0)
        assert board.stop_confirmed
    assert firmware.world.wheel_speeds == (0.0, 0.0) or max(map(abs, firmware.world.wheel_speeds)) < 1e-3


def test_penguinpi_drives_again_with_the_gain_restored_first(firmware: Firmware) -> None:
    board = firmware.board
    firmware.run(200, stopped=True)
    assert board.stop_confirmed and (firmware.fw.left.kvi, firmware.fw.right.kvi) == (0, 0)
    sent: list[bytes] = []
    firmware.tamper = lambda data: sent.append(data) or data
    firmware.run(1000, 0.15, 0.15)
    frames = [f for f in ppi.Parser().feed(b"".join(sent)) if isinstance(f, ppi.Frame)]
    kinds = [(f.address, f.opcode) for f in frames]
    first_demand = next(i for i, f in enumerate(frames) if f.opcode == ppi.MultiOp.MULTI_SET_VEL_GET_ENC
                        and f.payload != b"\x00\x00")
    assert kinds.index((ppi.Address.AD_MOTOR_R, ppi.MotorOp.MOTOR_SET_KVI)) < first_demand
    assert (firmware.fw.left.kvi, firmware.fw.right.kvi) == (1, 1) and not board.stop_confirmed
    assert firmware.world.wheel_speeds[0] == pytest.approx(0.15, rel=0.15)


def test_penguinpi_a_lost_gain_is_sent_again_and_only_then_confirmed(firmware: Firmware) -> None:
    board = firmware.board
    firmware.run(500, 0.2, 0.2)

    def corrupt_first_gain(data: bytes) -> bytes:  # one flipped bit in the right motor's SET
        at = data.find(ppi.encode_frame(ppi.Address.AD_MOTOR_R, ppi.MotorOp.MOTOR_SET_KVI, b"\0\0"))
        if at < 0:
            return data
        firmware.tamper = lambda d: d
        return data[:at + 5] + b"\x01" + data[at + 6:]

    firmware.tamper = corrupt_first_gain
    for _ in range(200):
        firmware.step(stopped=True)
        if board.stop_confirmed:  # never before the board really is stopped and clear
            assert firmware.fw.right.kvi == 0 and firmware.duty == (0.0, 0.0)
            assert firmware.integrators == (0, 0)
    assert board.stop_confirmed
    assert any("integral gain is 1, not 0; setting it again" in text for text in firmware.said)
    assert board.board_errors >= 1                     # the firmware's ERR: CRC failed


@pytest.mark.parametrize(("late_ms", "replies"), [(25, 1), (35, 2), (60, 3), (30, 40)])
def test_penguinpi_a_late_reply_is_counted_late_never_used(firmware: Firmware, late_ms: int,
                                                           replies: int) -> None:
    """(30, 40): every reply 30 ms later than the one before, for 40 replies: the line falls
    behind until every kind of request has timed out; then hwbridge waits for silence."""
    board = firmware.board
    firmware.run(300, 0.1, 0.1)
    counts: list[int] = []
    for _ in range(5):
        # The board answers the next requests (wheel exchanges and polls) past their timeout.
        firmware.delay_ms, firmware.delays = late_ms, replies
        for _ in range(300 + replies * late_ms):
            firmware.step(0.1, 0.1)
            counts.append(board.ticks_left)
            # What hwbridge reports is never ahead of what the board counted, nor goes back.
            assert board.ticks_left <= firmware.fw.left.position + 1
            assert len(counts) < 2 or counts[-1] >= counts[-2]
    assert board.timeouts == board.late > 0, (board.timeouts, board.late)
    assert board.unmatched == 0 and board.crc_errors == 0
    assert late_ms * MS > REPLY_TIMEOUT_NS
    # Encoder counts stayed true: hwbridge's last sample is the firmware's count of then.
    assert abs(board.ticks_left - firmware.fw.left.position) <= 10


class ModelTransport:
    """The icoBoard model as a transport: one exchange at the test's simulated time."""

    def __init__(self, model: IcoBoardModel) -> None:
        self.model, self.now = model, 0.0

    def exchange(self, frame: bytes, timeout_s: float) -> bytes | None:
        return self.model.exchange(frame, self.now)

    def drain(self) -> int:
        return 0

    def close(self) -> None:
        pass


@pytest.mark.parametrize("protocol", [2, 1])
def test_icoboard_stop_zero_duty_at_once_confirmed_by_the_next_exchange(protocol: int) -> None:
    config = msgspec.convert({"board": {"kind": "icoboard", "protocol": protocol}}, RobotConfig)
    world = World(config.geometry, seed=1)
    model = IcoBoardModel(world, Wire.for_board(config.board))
    transport = ModelTransport(model)
    board = IcoBoardBoard(config, lambda kind, text: None)
    board._connect = lambda: transport  # type: ignore[method-assign]
    board.clock = lambda: round(transport.now * 1e9)  # replies arrive in simulated time
    board.open(0)
    for ms in range(1, 1001):
        transport.now = ms * 1e-3
        world.step(0.001)
        board.cycle(ms * MS, 0.2, 0.2, stopped=False)
    assert model.duty[0] > 0 and board._pi[0].integral != 0 and not board.stop_confirmed
    world.step(0.001)
    board.cycle(1001 * MS, 0.0, 0.0, stopped=True)
    assert model.duty == (0.0, 0.0)                    # the stopped exchange itself
    assert board._pi[0].integral == board._pi[1].integral == 0.0
    assert not board.stop_confirmed                    # not yet acknowledged
    board.cycle(1002 * MS, 0.0, 0.0, stopped=True)
    assert board.stop_confirmed                        # the next reply acknowledged it
    board.cycle(1003 * MS, 0.1, 0.1, stopped=False)
    assert not board.stop_confirmed


class FakeBoard(Board):
    name = "fake"

    def open(self, now_ns: int) -> None:
        pass

    def cycle(self, now_ns: int, left: float, right: float, stopped: bool, until_ns: int = 0) -> None:
        if not stopped:
            self.stop_confirmed = False


@pytest.fixture
def shared():
    s = Shared.create()
    yield s
    s.close()


def test_cycle_reports_a_stop_confirmed_only_once_the_board_is(shared) -> None:
    board = FakeBoard(RobotConfig(), lambda kind, text: None)
    cycle = Cycle(RobotConfig(), shared, board)
    t = 10**9
    shared.write_commands(0.2, 0.2, t, False, 0, 0)
    cycle.step(t)
    shared.write_commands(0.0, 0.0, t, True, 0, 3)   # stop number 3 latched
    cycle.step(t + MS)
    assert shared.read_state()["stop_confirmed"] == 0
    board.stop_confirmed = True
    cycle.step(t + 2 * MS)
    assert shared.read_state()["stop_confirmed"] == 3
    # Zero targets without a stop are a stop for the board, but confirm no stop number.
    shared.write_commands(0.0, 0.0, t + 3 * MS, False, 0, 3)
    cycle.step(t + 3 * MS)
    assert shared.read_state()["stop_confirmed"] == 3


def state(shared: Shared, **fields: int) -> None:
    values: list[float | int] = [0] * len(STATE_FIELDS)
    for name, value in fields.items():
        values[STATE_FIELDS.index(name)] = value
    shared.write_state(values)


async def test_halt_and_motion_answer_only_after_the_confirmation(shared) -> None:
    bridge = Bridge(RobotConfig(), shared, logging.getLogger("test"))
    number = bridge.stop("cmd/halt")
    halt = asyncio.ensure_future(bridge.halt(m.Halt(rest=False), number))
    await asyncio.sleep(0.05)
    assert not halt.done()
    state(shared, stop_confirmed=number, sample_ns=time.monotonic_ns())
    await asyncio.wait_for(halt, 1.0)
    # A timed motion's end is a stop too: MotionDone waits for its confirmation.
    motion = asyncio.ensure_future(bridge.motion(m.Motion(left=0.1, right=0.1, duration=0.05),
                                                 Origin(time.monotonic_ns())))
    await asyncio.sleep(0.2)
    assert not motion.done() and bridge.stop_seq == number + 1
    state(shared, stop_confirmed=number + 1)
    done = await asyncio.wait_for(motion, 1.0)
    assert done.completed


async def test_a_stop_released_before_its_confirmation_is_not_confirmed(shared) -> None:
    bridge = Bridge(RobotConfig(), shared, logging.getLogger("test"))
    number = bridge.stop("cmd/halt", Origin.of(time.monotonic_ns(), "a", 5, 1000))
    halt = asyncio.ensure_future(bridge.halt(m.Halt(rest=False), number))
    # A command a issued before its stop arrives now: refused, the stop stays latched.
    assert not bridge.command(0.1, 0.1, "cmd/wheels", Origin.of(time.monotonic_ns(), "a", 4, 900))
    assert bridge.dropped == 1 and shared.read_commands()[3] == 1
    # One issued after it releases it before the board confirmed: the halt says so.
    assert bridge.command(0.1, 0.1, "cmd/wheels", Origin.of(time.monotonic_ns(), "a", 6, 1100))
    with pytest.raises(NotConfirmed, match="released it before the board confirmed"):
        await asyncio.wait_for(halt, 1.0)


def test_penguinpi_button_presses_in_a_late_reply_are_not_lost(firmware: Firmware) -> None:
    """HAT_GET_BUTTON clears the board's count when it is read: its late reply still counts."""
    board = firmware.board
    firmware.run(200, 0.1, 0.1)
    firmware.delay_only = ppi.encode_frame(ppi.Address.AD_HAT, ppi.HatOp.HAT_GET_BUTTON, b"\0")[:4]
    for _ in range(3):
        firmware.fw.hat.press("S4")
        firmware.delay_ms, firmware.delays = 30, 1    # the next button read answers late
        firmware.run(300, 0.1, 0.1)
    assert board.late == 3 and board.unmatched == 0
    assert board.button_presses == 3
