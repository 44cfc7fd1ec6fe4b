"""The simulator's 1 kHz clock, with an injected fake clock so its schedule is tested exactly."""

from __future__ import annotations

import threading

import pytest

from icefloe.config import Geometry
from icefloe.sim.clock import SimClock
from icefloe.sim.world import World


class FakeTime:
    """A wall clock that moves only when the code under test sleeps (or a step costs time)."""

    def __init__(self, step_cost: float = 0.0) -> None:
        self.t = 100.0
        self.step_cost = step_cost
        self.sleeps: list[float] = []

    def clock(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.t += seconds


class Recorder:
    """A board that records the times it was ticked, and charges each tick to the fake clock."""

    def __init__(self, fake: FakeTime, stop_after: int, done: threading.Event) -> None:
        self.fake, self.stop_after, self.done = fake, stop_after, done
        self.times: list[float] = []

    def tick(self, now: float) -> None:
        self.times.append(now)
        self.fake.t += self.fake.step_cost
        if len(self.times) == self.stop_after:
            self.done.set()


def run_clock(step_cost: float, steps: int, **kwargs: float) -> tuple[SimClock, FakeTime, Recorder]:
    fake = FakeTime(step_cost)
    done = threading.Event()
    board = Recorder(fake, steps, done)
    clock = SimClock(World(Geometry(), seed=1), [board], clock=fake.clock, sleep=fake.sleep,
                     **kwargs)
    clock.start()
    assert done.wait(5.0)
    clock.stop()
    return clock, fake, board


def test_synchronous_run_is_exact() -> None:
    world = World(Geometry(), seed=1)
    fake = FakeTime()
    board = Recorder(fake, -1, threading.Event())
    clock = SimClock(world, [board])
    clock.run(0.005)
    assert board.times == pytest.approx([0.001, 0.002, 0.003, 0.004, 0.005])
    assert world.time == pytest.approx(0.005)


def test_real_time_sleeps_the_rest_of_each_period() -> None:
    clock, fake, board = run_clock(step_cost=0.0002, steps=50)
    assert board.times[:3] == pytest.approx([0.001, 0.002, 0.003])
    # Each step costs 0.2 ms of the 1 ms period: it sleeps the remaining 0.8 ms.
    assert fake.sleeps[:10] == pytest.approx([0.0008] * 10)
    assert clock.late_steps == 0 and clock.dropped == 0


def test_faster_than_real_time() -> None:
    _, fake, _ = run_clock(step_cost=0.0, steps=40, speed=4.0)
    assert fake.sleeps[:10] == pytest.approx([0.00025] * 10)


def test_late_steps_catch_up_then_drop_backlog() -> None:
    # Each step costs 3 ms of a 1 ms period: always late; after max_catch_up steps in a row
    # the backlog is dropped instead of racing forever.
    clock, fake, board = run_clock(step_cost=0.003, steps=30, max_catch_up=5)
    assert fake.sleeps == []
    assert clock.late_steps >= 30
    assert clock.dropped > 0
    # Simulated time still advances exactly one dt per step.
    assert board.times[:30] == pytest.approx([0.001 * (i + 1) for i in range(30)])


def test_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="dt and speed"):
        SimClock(World(Geometry(), seed=1), speed=0.0)


def test_running_says_whether_the_thread_steps_and_a_raising_model_ends_it() -> None:
    """`running` is what the simulator's truth task watches: False once a board model raised in
    the clock thread (or `stop` ended it). The SIGSTOP case, end to end, is
    tests/test_doctor.py::test_the_board_unplugged_is_named."""

    class Breaks:
        def tick(self, now: float) -> None:
            if now >= 0.01:
                raise RuntimeError("a board model broke")

    world = World(Geometry())
    clock = SimClock(world, [Breaks()])
    assert not clock.running
    events: list[threading.ExceptHookArgs] = []
    hook, threading.excepthook = threading.excepthook, events.append
    try:
        clock.start()
        assert clock._thread is not None
        clock._thread.join(5.0)
    finally:
        threading.excepthook = hook
    assert not clock.running and "a board model broke" in str(events[0].exc_value)
    steady = SimClock(World(Geometry()))
    with steady:
        assert steady.running
    assert not steady.running
