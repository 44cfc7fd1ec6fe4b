"""hwbridge's ``cmd/car`` path (`Bridge.car`, `Bridge.car_step`) on a real shared-memory block,
without the cycle: the targets it writes for the cycle are read back; times are passed in."""

from __future__ import annotations

import asyncio
import logging
import threading
import time

import pytest
from test_motion_car import TRACK, centre_radius

from icefloe.config import RobotConfig
from icefloe.motion.car import turn_radius
from icefloe.ordering import Origin
from icefloe.schemas import messages as m
from icefloe.services.hwbridge.bridge import Bridge
from icefloe.services.hwbridge.shm import Shared

assert RobotConfig().geometry.track == TRACK


class Lines(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


@pytest.fixture
def bridge():
    """A `Bridge` on a real shared-memory block (no cycle: we read the targets it writes)."""
    shared = Shared.create()
    log = logging.getLogger(f"test-car-{id(shared)}")
    lines = Lines()
    log.addHandler(lines)
    loop = asyncio.new_event_loop()
    asyncio.set_event_loop(loop)
    try:
        made = loop.run_until_complete(_make(shared, log))
        made.lines = lines.lines  # type: ignore[attr-defined]
        yield made
    finally:
        shared.close()
        asyncio.set_event_loop(None)
        loop.close()


async def _make(shared: Shared, log: logging.Logger) -> Bridge:
    return Bridge(RobotConfig(), shared, log)


def targets(bridge: Bridge) -> tuple[float, float, bool]:
    left, right, _fresh, stop, _epoch, _seq = bridge.shared.read_commands()
    return left, right, bool(stop)


def test_a_car_command_drives_steers_step_by_step_and_a_stop_wins(bridge: Bridge) -> None:
    t0 = time.monotonic_ns()
    assert bridge.car(m.CarDrive(v=0.1, steer=0.6), Origin(t0))
    left, right, stopped = targets(bridge)
    assert left == right == pytest.approx(0.1) and not stopped  # the steering has not turned yet
    state = bridge.car_step(t0 + 200_000_000)  # 0.2 s later: 0.3 rad
    assert state.steer == pytest.approx(0.3) and state.driving
    left, right, _ = targets(bridge)
    assert centre_radius(left, right) == pytest.approx(turn_radius(0.3, 0.15))
    stopper = threading.Thread(target=bridge.stop)  # cmd/stop, latched on a Zenoh thread
    stopper.start()
    stopper.join()
    state = bridge.car_step(t0 + 400_000_000)  # a step after the stop must not drive
    assert targets(bridge) == (0.0, 0.0, True)
    assert not state.driving and state.v == 0.0 and state.steer == state.steer_target


def test_a_car_command_issued_before_the_last_stop_never_drives(bridge: Bridge) -> None:
    t0 = time.monotonic_ns()
    bridge.stop("cmd/stop", Origin(t0, "student", 5))
    assert not bridge.car(m.CarDrive(v=0.2, steer=0.0), Origin(t0 + 1_000_000, "student", 4))
    assert targets(bridge) == (0.0, 0.0, True)
    assert any("cmd/car: not applied: issued before a stop" in line for line in bridge.lines)
    assert bridge.car(m.CarDrive(v=0.2, steer=0.0), Origin(t0 + 2_000_000, "student", 6))
    assert targets(bridge)[:2] == pytest.approx((0.2, 0.2))


def test_the_car_parks_at_the_deadman_and_on_another_command(bridge: Bridge) -> None:
    t0 = time.monotonic_ns()
    bridge.car(m.CarDrive(v=0.1, steer=0.6), Origin(t0))
    bridge.car_step(t0 + 300_000_000)
    state = bridge.car_step(t0 + 600_000_000)  # the deadman (0.5 s) has passed
    assert not state.driving and state.steer == pytest.approx(0.6)  # it had arrived at 0.4 s
    assert state.x == pytest.approx(bridge.car_step(t0 + 900_000_000).x)  # it stands still
    bridge.car(m.CarDrive(v=0.1, steer=0.0), Origin(t0 + 1_000_000_000))
    bridge.command(0.05, 0.05, "cmd/wheels", Origin(t0 + 1_100_000_000))
    state = bridge.car_step(t0 + 1_200_000_000)
    assert not state.driving and targets(bridge)[:2] == (0.05, 0.05)  # the car does not steer cmd/wheels


def test_clipped_and_slowed_each_say_so(bridge: Bridge) -> None:
    t0 = time.monotonic_ns()
    bridge.car(m.CarDrive(v=0.5, steer=1.0), Origin(t0))
    bridge.car_step(t0 + 450_000_000)
    assert "cmd/car: steer 1 rad is beyond car.max_steer (0.6 rad): clipped to 0.600 rad" in bridge.lines
    assert any(line.startswith("cmd/car: v 0.5 m/s at steer 0.600 rad needs a wheel beyond "
                               "hwbridge.max_wheel_speed (0.5 m/s): slowed to ") for line in bridge.lines)
    left, right, _ = targets(bridge)
    assert max(abs(left), abs(right)) == pytest.approx(0.5)


def test_a_hostile_value_gets_one_short_line(bridge: Bridge) -> None:
    """The largest finite floats: clipped and slowed, each said in a line of ordinary length."""
    t0 = time.monotonic_ns()
    assert bridge.car(m.CarDrive(v=1.7e308, steer=-1e308), Origin(t0))
    lines = [line for line in bridge.lines if line.startswith("cmd/car: ")]
    assert lines[0] == "cmd/car: steer -1e+308 rad is beyond car.max_steer (0.6 rad): clipped to -0.600 rad"
    assert lines[1].startswith("cmd/car: v 1.7e+308 m/s at steer 0.000 rad needs a wheel beyond")
    assert all(len(line) < 200 for line in lines)
    left, right, _ = targets(bridge)
    assert left == right == 0.5



def test_a_car_command_that_drives_wakes_the_idle_cars_loop(bridge: Bridge) -> None:
    """An idle car's loop waits for `car_commanded` (``__main__.car_loop``): a cmd/car that drives
    sets it, from whichever thread it came on; one that is refused does not."""
    loop = asyncio.get_event_loop()
    t0 = time.monotonic_ns()
    bridge.stop("cmd/stop", Origin(t0, "student", 5))
    assert not bridge.car(m.CarDrive(v=0.2, steer=0.0), Origin(t0 + 1_000_000, "student", 4))
    loop.run_until_complete(asyncio.sleep(0))
    assert not bridge.car_commanded.is_set()
    command = (m.CarDrive(v=0.2, steer=0.3), Origin(t0 + 2_000_000, "student", 6))
    sender = threading.Thread(target=bridge.car, args=command)  # a Zenoh thread
    sender.start()
    sender.join()
    loop.run_until_complete(asyncio.sleep(0))
    assert bridge.car_commanded.is_set()
