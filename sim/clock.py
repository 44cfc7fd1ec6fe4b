"""The simulator's 1 kHz clock: steps the World, then ticks each board, in its own thread.

    clock = SimClock(world, [board])            # board: anything with tick(now)
    clock.start(); ...; clock.stop()            # real time (speed=1.0), or faster for tests

The thread keeps an absolute schedule: step n is due at start + n·dt/speed
(wall seconds). When it is late it steps without sleeping until it has caught
up, at most `max_catch_up` steps in a row; beyond that it drops the backlog
(counted in `dropped`) rather than race forever. Simulated time (`now`) always
advances exactly dt per step, so everything a board does is exact in sim time.
`run(seconds)` steps synchronously, without the thread, for exact unit tests.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from typing import Protocol

from .world import World


class Ticked(Protocol):
    def tick(self, now: float) -> None: ...


class SimClock:
    """Steps ``world`` by ``dt`` and calls ``tick(now)`` on each board, at ``speed`` x real time."""

    def __init__(self, world: World, boards: Sequence[Ticked] = (), *, dt: float = 0.001,
                 speed: float = 1.0, max_catch_up: int = 100,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        if not dt > 0 or not speed > 0:
            raise ValueError("dt and speed must be positive")
        self.world = world
        self.boards = list(boards)
        self.dt = dt
        self.speed = speed
        self.max_catch_up = max_catch_up
        self._clock = clock
        self._sleep = sleep
        self.steps = 0
        """Steps taken; simulated time is steps * dt."""
        self.late_steps = 0
        """Steps that started after their due time (caught up without sleeping)."""
        self.dropped = 0
        """Steps skipped because the thread fell more than `max_catch_up` steps behind."""
        self.paused = False
        """The world is frozen: the robot does not move, its encoders do not count; the boards
        still tick (their timers, controllers and serial links run on), so a stop reaches them."""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    @property
    def now(self) -> float:
        """Simulated seconds since the clock started."""
        return self.steps * self.dt

    def step(self) -> None:
        """One step: physics first (unless `paused`), then every board sees the new state at the new time."""
        with self._lock:
            if not self.paused:
                self.world.step(self.dt)
            self.steps += 1
            now = self.now
            for board in self.boards:
                board.tick(now)

    def run(self, seconds: float) -> None:
        """Step synchronously through ``seconds`` of simulated time (no thread, no sleeping)."""
        for _ in range(round(seconds / self.dt)):
            self.step()

    def start(self) -> SimClock:
        if self._thread is not None:
            raise RuntimeError("clock already started")
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="sim-clock", daemon=True)
        self._thread.start()
        return self

    @property
    def running(self) -> bool:
        """The clock thread is stepping (False once `stop` ended it, or a board model raised in it)."""
        return self._thread is not None and self._thread.is_alive()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None

    def __enter__(self) -> SimClock:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _loop(self) -> None:
        period = self.dt / self.speed                # wall seconds per step
        due = self._clock()
        behind = 0
        while not self._stop.is_set():
            self.step()
            due += period
            lag = self._clock() - due
            if lag <= 0:
                behind = 0
                self._sleep(-lag)
                continue
            self.late_steps += 1
            behind += 1
            if behind > self.max_catch_up:
                skipped = int(lag / period)
                self.dropped += skipped
                due += skipped * period
                behind = 0
