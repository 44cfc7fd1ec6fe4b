"""Board backends and the cycle, driven step by step with an injected clock.

The PenguinPi backend runs real pyserial on a pseudo-terminal; the test plays the
board's end byte by byte. The cycle (`rt.Cycle`) runs on real shared memory.
"""

from __future__ import annotations

import array
import asyncio
import contextlib
import fcntl
import logging
import os
import select
import termios
import threading
import time
import tty

import msgspec
import pytest

from icefloe.config import RobotConfig
from icefloe.errors import BoardError
from icefloe.ordering import Origin
from icefloe.schemas import messages as m
from icefloe.services.hwbridge import control
from icefloe.services.hwbridge.board import Board
from icefloe.services.hwbridge.bridge import Bridge
from icefloe.services.hwbridge.penguinpi import OPEN_FRAMES, STOP_FRAMES, PenguinPiBoard, board_text, set_gains
from icefloe.services.hwbridge.rt import PUBLISH_PERIODS, Cycle
from icefloe.services.hwbridge.shm import IO_LED, IO_TEXT, MSG_WARNING, OFF_STATE_SEQ, Shared
from icefloe.wire import penguinpi as ppi

MS = 1_000_000


class BoardEnd:
    """The board's side of a pseudo-terminal whose other end the backend opens."""

    def __init__(self, tmp_path) -> None:
        self.master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(self.master, False)
        self.path = tmp_path / "tty"
        self.path.symlink_to(os.ttyname(slave))
        self._slave = slave

    def read(self, frames: int = 0) -> bytes:
        """What the backend has written; with ``frames``, waits (up to 5 s) until that many whole
        PenguinPi frames are there: the kernel hands a pseudo-terminal's bytes over in its own time."""
        data, deadline = b"", time.monotonic() + 5.0
        while True:
            with contextlib.suppress(BlockingIOError):
                data += os.read(self.master, 4096)
            if len(ppi.Parser().feed(data)) >= frames or time.monotonic() > deadline:
                return data
            select.select([self.master], [], [], 0.05)

    def write(self, data: bytes) -> None:
        """Send ``data`` to the backend, and wait (up to 5 s) until its line discipline holds it: the
        backend reads only the bytes the kernel has handed over (FIONREAD), as a real cycle then
        reads them a period later."""
        waiting = array.array("i", [0])
        fcntl.ioctl(self._slave, termios.FIONREAD, waiting, True)
        expected, deadline = waiting[0] + len(data), time.monotonic() + 5.0
        os.write(self.master, data)
        while waiting[0] < expected and time.monotonic() < deadline:
            time.sleep(0.001)
            fcntl.ioctl(self._slave, termios.FIONREAD, waiting, True)

    def close(self) -> None:
        os.close(self.master)
        os.close(self._slave)


@pytest.fixture
def penguin(tmp_path):
    end = BoardEnd(tmp_path)
    config = msgspec.convert({"board": {"serial_port": str(end.path)}}, RobotConfig)
    said: list[tuple[int, str]] = []
    board = PenguinPiBoard(config, lambda kind, text: said.append((kind, text)))
    board.open(0)
    # Stopped, both gains 0 (the firmware's integrator cleared at its next step).
    assert end.read() == OPEN_FRAMES
    yield board, end, said
    board.close()
    end.close()


def multi_reply(left: int, right: int) -> bytes:
    return ppi.encode_frame(ppi.Address.AD_MULTI, ppi.MultiOp.MULTI_SET_VEL_GET_ENC,
                            ppi.pack_multi_get(left, right))


def test_penguinpi_exchange_units_order_and_matching(penguin) -> None:
    board, end, _ = penguin
    board.cycle(1 * MS, 0.15, -0.05, stopped=False)
    sent = end.read()
    assert sent.startswith(set_gains(1)), "the integral gain first, then the demands"
    frame = ppi.Parser().feed(sent)[2]
    assert (frame.address, frame.opcode) == (ppi.Address.AD_MULTI, ppi.MultiOp.MULTI_SET_VEL_GET_ENC)
    left, right = ppi.unpack_multi_set(frame.payload)  # right-first on the wire
    assert (left, right) == (30, -10)                  # dithered demands: 5 x counts per 20 ms
    board.cycle(2 * MS, 0.15, -0.05, stopped=False)
    assert end.read() == b"", "nothing new while a request is in flight"
    end.write(multi_reply(32760, -32760))              # reply is left-first
    board.cycle(3 * MS, 0.15, -0.05, stopped=False)
    assert (board.ticks_left, board.ticks_right, board.exchanges) == (0, 0, 1)
    # Between wheel exchanges come the slow polls (battery first); answer like the firmware.
    board.cycle(4 * MS, 0.15, -0.05, stopped=False)
    poll = ppi.Parser().feed(end.read())[0]
    assert (poll.address, poll.opcode) == (ppi.Address.AD_ADC_V, ppi.AdcOp.ADC_GET_SMOOTH)
    end.write(ppi.encode_frame(poll.address, poll.opcode, ppi.pack_float(7400.0)))
    # Counts unwrap across the 16-bit wrap.
    board.cycle(6 * MS, 0.15, -0.05, stopped=False)
    assert board.battery_voltage == pytest.approx(7.4)
    assert ppi.Parser().feed(end.read())[0].address == ppi.Address.AD_MULTI
    end.write(multi_reply(-32766, 32766))
    board.cycle(7 * MS, 0.15, -0.05, stopped=False)
    assert (board.ticks_left, board.ticks_right) == (10, -10)  # forward and back across the wrap


def test_penguinpi_resynchronises_within_one_frame(penguin) -> None:
    board, end, said = penguin
    board.cycle(1 * MS, 0.1, 0.1, stopped=False)
    end.read()
    bad = bytearray(multi_reply(1, 1))
    bad[-1] ^= 0xFF                                    # corrupted CRC
    lost = multi_reply(2, 2)[:-3]                      # a frame that lost its tail
    # garbage, a text line, a corrupted frame, a truncated frame, then the good reply
    end.write(b"\xff\xfe" + b"ERR: CRC failed\n" + bytes(bad) + lost + multi_reply(40, 41))
    board.cycle(2 * MS, 0.1, 0.1, stopped=False)
    assert board.exchanges == 1 and (board.ticks_left, board.ticks_right) == (0, 0)
    assert board.crc_errors >= 1 and board.garbage_bytes >= 2 and board.board_errors == 1
    assert (MSG_WARNING, "PenguinPi: ERR: CRC failed") in said
    # A late duplicate reply matches nothing: counted, not used.
    end.write(multi_reply(99, 99))
    board.cycle(3 * MS, 0.1, 0.1, stopped=False)
    assert board.unmatched == 1 and board.ticks_left == 0
    # No reply at all (to the battery poll that went out at 2 ms): a timeout after 20 ms, then
    # the next exchange goes out (tests/test_hwbridge_stops.py: what a late reply does then).
    board.cycle(10 * MS, 0.1, 0.1, stopped=False)
    end.read()
    board.cycle(40 * MS, 0.1, 0.1, stopped=False)
    assert board.timeouts == 1
    assert ppi.Parser().feed(end.read())[0].opcode == ppi.MultiOp.MULTI_SET_VEL_GET_ENC


def test_penguinpi_io_commands_and_stop(penguin) -> None:
    board, end, _ = penguin
    board.io(IO_LED, 2, 100, b"")
    board.io(IO_TEXT, 0, 0, b"hi\x11\x00\n")
    board.cycle(1 * MS, 0.1, 0.1, stopped=False)      # the wheel exchange goes first
    frames = ppi.Parser().feed(end.read())
    assert ppi.unpack_multi_set(frames[2].payload) != (0, 0)
    end.write(multi_reply(0, 0))
    board.cycle(2 * MS, 0.1, 0.1, stopped=False)
    assert end.read() == ppi.encode_frame(ppi.Address.AD_LED_2, ppi.LedOp.LED_SET_COUNT, bytes([100]))
    board.cycle(3 * MS, 0.1, 0.1, stopped=False)
    assert end.read() == b"hi\n"                      # 0x11 would start a frame: removed
    assert board_text(b"a\x0cb\xe9") == b"a\x0cb"
    board.stop()
    assert end.read() == STOP_FRAMES


def test_penguinpi_link_lost_raises_board_error(penguin) -> None:
    board, end, _ = penguin
    end.close()
    with pytest.raises(BoardError, match="tty"):
        for t in range(1, 5):
            board.cycle(t * MS, 0.1, 0.1, stopped=False)
    end.master = os.open("/dev/null", os.O_RDONLY)   # so the fixture's close has fds to close
    end._slave = os.open("/dev/null", os.O_RDONLY)


class FakeBoard(Board):
    """A board that records what the cycle asks of it (the cycle's logic is under test)."""

    name = "fake"

    def __init__(self, config: RobotConfig) -> None:
        super().__init__(config, lambda kind, text: None)
        self.calls: list[tuple[int, float, float, bool]] = []
        self.until_ns = 0
        self.fail_next = False
        self.link: list[str] = []
        """open, stop and close, in the order the cycle called them."""

    def open(self, now_ns: int) -> None:
        self.link.append("open")

    def stop(self) -> None:
        self.link.append("stop")

    def close(self) -> None:
        self.link.append("close")

    def cycle(self, now_ns: int, left: float, right: float, stopped: bool, until_ns: int = 0) -> None:
        if self.fail_next:
            self.fail_next = False
            raise BoardError("fake: gone")
        self.calls.append((now_ns, left, right, stopped))
        self.until_ns = until_ns


@pytest.fixture
def shared():
    s = Shared.create()
    yield s
    s.close()


def test_cycle_deadman_stop_latch_limits_and_ramp(shared) -> None:
    config = msgspec.convert({"hwbridge": {"max_accel": 2.0, "max_wheel_speed": 0.5}}, RobotConfig)
    board = FakeBoard(config)
    cycle = Cycle(config, shared, board)
    t = 10**9
    cycle.step(t)
    assert board.calls[-1][3] and cycle.stop_reason == control.STOP_NEVER_COMMANDED
    shared.write_commands(2.0, 0.2, t, False, 0)      # 2.0 m/s: over the limit
    cycle._last_dt = 0.001
    for i in range(1, 101):
        cycle.step(t + i * MS)
    _, left, right, stopped = board.calls[-1]
    assert not stopped
    assert left == pytest.approx(0.2) and right == pytest.approx(0.2)  # 2 m/s^2 for 0.1 s
    for i in range(101, 300):
        cycle.step(t + i * MS)
    assert board.calls[-1][1:3] == pytest.approx((0.5, 0.2))  # clamped to max_wheel_speed
    # Deadman: still driving at exactly 0.5 s after the command, stopped one cycle later.
    cycle.step(t + 500 * MS)
    assert not board.calls[-1][3]
    cycle.step(t + 500 * MS + 1)
    assert board.calls[-1][3] and cycle.stop_reason == control.STOP_DEADMAN
    assert cycle.target_left == 0.0
    # The stop latch holds even with a fresh command time, until the bus side clears it.
    shared.write_commands(0.3, 0.3, t + 600 * MS, True, 0)
    cycle.step(t + 601 * MS)
    assert cycle.stop_reason == control.STOP_LATCHED
    state = shared.read_state()
    assert state["stop_reason"] == control.STOP_LATCHED and state["target_left"] == 0.0


def test_cycle_survives_a_lost_link_and_retries(shared) -> None:
    config = RobotConfig()
    board = FakeBoard(config)
    cycle = Cycle(config, shared, board)
    cycle.step(MS)
    assert cycle.link_up
    board.fail_next = True
    cycle.step(2 * MS)
    assert not cycle.link_up
    cycle.step(3 * MS)                                 # no retry before a second has passed
    assert not cycle.link_up
    cycle.step(2 * MS + 10**9)
    assert cycle.link_up
    lines, _ = shared.pop_messages()
    assert any("board link lost: fake: gone" in text for _, text in lines)


def test_shutdown_opens_a_lost_link_once_more_to_stop_the_board(shared) -> None:
    """SIGTERM within the second between a lost link and its retry: the board still hears
    the stop (EXIT on the icoBoard), not only the zero-duty frame of the lost link."""
    board = FakeBoard(RobotConfig())
    cycle = Cycle(RobotConfig(), shared, board)
    cycle.step(MS)
    cycle.shutdown()
    assert board.link == ["open", "stop", "close"]     # the link was up: stopped, no reopening
    board = FakeBoard(RobotConfig())
    cycle = Cycle(RobotConfig(), shared, board)
    cycle.step(MS)
    board.fail_next = True
    cycle.step(2 * MS)                                 # lost: stop_lost (= stop here), close
    assert not cycle.link_up and board.link == ["open", "stop", "close"]
    board.link.clear()
    cycle.shutdown()
    assert board.link == ["open", "stop", "close"]


def test_the_state_is_written_at_once_on_news_else_every_tenth_period(shared) -> None:
    """The cycle writes its state when the bus side has news (`rt.PUBLISH_PERIODS`): a new
    exchange with the board, a stop (latched or the deadman), a stop confirmed, the link lost.
    Each is in the state in the period it happened; with no news, the loop's counters still
    come every 10th period."""
    config = RobotConfig()
    board = FakeBoard(config)
    cycle = Cycle(config, shared, board)
    t = 10**9

    def period(i: int) -> None:  # what `Cycle.run` does around `step`
        cycle.step(t + i * MS)
        cycle.cycles += 1

    def writes() -> int:
        return shared._word(OFF_STATE_SEQ) // 2

    shared.write_commands(0.2, 0.2, t, False, 0)
    period(0)
    assert shared.read_state()["stop_reason"] == control.STOP_NONE
    first = writes()
    for i in range(1, PUBLISH_PERIODS):  # the fake board exchanges nothing: no news
        period(i)
    assert writes() == first
    period(PUBLISH_PERIODS)
    assert writes() == first + 1 and shared.read_state()["cycles"] == PUBLISH_PERIODS
    board.exchanges += 1                                 # a new encoder sample
    period(PUBLISH_PERIODS + 1)
    assert writes() == first + 2 and shared.read_state()["exchanges"] == 1
    shared.write_commands(0.0, 0.0, t, True, 0, 1)       # cmd/stop latched
    board.stop_confirmed = True
    period(PUBLISH_PERIODS + 2)
    state = shared.read_state()
    assert state["stop_reason"] == control.STOP_LATCHED and state["stop_confirmed"] == 1
    assert state["duty_left"] == state["duty_right"] == 0.0 and writes() == first + 3
    board.fail_next = True                               # the link lost
    period(PUBLISH_PERIODS + 3)
    assert shared.read_state()["link_up"] == 0 and writes() == first + 4


def test_a_stop_goes_out_between_periods_once(shared) -> None:
    config = RobotConfig()
    board = FakeBoard(config)
    cycle = Cycle(config, shared, board)
    t = 10**9
    shared.write_commands(0.2, 0.2, t, False, 0)
    cycle.step(t)
    assert not board.calls[-1][3]
    deadline = t + MS                                  # the next period
    cycle.stop_now(t + MS // 2, deadline)              # no stop latched: nothing to do
    assert len(board.calls) == 1
    shared.write_commands(0.0, 0.0, t, True, 0)       # the bus side latches cmd/stop...
    cycle.stop_now(deadline - MS // 8 + 1, deadline)   # ...too close to the period: it waits
    assert len(board.calls) == 1
    cycle.stop_now(t + MS // 2, deadline)              # ...in good time: the stop goes now
    assert board.calls[-1] == (t + MS // 2, 0.0, 0.0, True)
    assert deadline - MS // 8 < board.until_ns < deadline  # it gives up on the reply in time
    assert cycle.stop_reason == control.STOP_LATCHED and shared.read_state()["kicks"] == 1
    cycle.stop_now(t + MS // 2 + 1, deadline)          # already stopped: no extra exchange
    assert len(board.calls) == 2


def test_penguinpi_stop_does_not_wait_for_the_exchange_slot(penguin) -> None:
    board, end, _ = penguin
    board.cycle(1 * MS, 0.15, 0.15, stopped=False)
    assert ppi.Parser().feed(end.read())[-1].opcode == ppi.MultiOp.MULTI_SET_VEL_GET_ENC
    end.write(multi_reply(0, 0))
    board.cycle(2 * MS, 0.15, 0.15, stopped=False)   # the next wheel slot is 5 ms after the first
    poll = ppi.Parser().feed(end.read())[0]
    assert poll.address == ppi.Address.AD_ADC_V      # the link is free: a slow poll goes
    end.write(ppi.encode_frame(poll.address, poll.opcode, ppi.pack_float(7400.0)))
    board.cycle(3 * MS, 0.0, 0.0, stopped=True)       # stop: at once, not at 6 ms
    sent = end.read(frames=len(ppi.Parser().feed(STOP_FRAMES)) + 1)
    assert sent.startswith(STOP_FRAMES)               # gains 0 and MULTI_ALL_STOP...
    frame = ppi.Parser().feed(sent[len(STOP_FRAMES):])[0]
    assert frame.opcode == ppi.MultiOp.MULTI_SET_VEL_GET_ENC  # ...and the wheel exchange
    assert ppi.unpack_multi_set(frame.payload) == (0, 0)


async def test_a_stop_wins_over_a_motion_step_that_has_not_seen_it(shared) -> None:
    bridge = Bridge(RobotConfig(), shared, logging.getLogger("test"))
    motion = asyncio.ensure_future(bridge.motion(m.Motion(left=0.1, right=0.1, duration=5.0),
                                                 Origin(time.monotonic_ns())))
    await asyncio.sleep(0.05)
    assert shared.read_commands()[:2] == (0.1, 0.1) and not shared.read_commands()[3]
    since = bridge.changes
    stopper = threading.Thread(target=bridge.stop)    # cmd/stop, latched on a Zenoh thread
    stopper.start()
    stopper.join()
    # The motion's next step runs before the loop tells it that it was cut: it must not drive.
    bridge.motion_step(0.1, 0.1, since)
    assert shared.read_commands()[:2] == (0.0, 0.0) and shared.read_commands()[3] == 1
    done = await asyncio.wait_for(motion, 1.0)
    assert not done.completed and done.reason == "cmd/stop"
    bridge.command(0.1, 0.1, "cmd/twist", Origin(time.monotonic_ns()))  # a new command releases it
    assert shared.read_commands()[3] == 0
