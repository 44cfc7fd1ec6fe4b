"""The simulated icoBoard as its real gateware: `icefloe.gateware` compiled, pins wired to the world.

Chosen with ``[sim] icoboard = "gateware"`` in a robot config. It sits behind the
same datagram socket as the Python model (`icefloe.sim.icoboard.IcoBoardSim`), so
hwbridge and everything above it cannot tell the two apart. What differs is who
answers: here every request is clocked bit by bit through the gateware's SPI
pins, and the world is connected to its other pins:

* the world's wheels drive the encoder pins: each simulated millisecond the
  phases step to the world's counts, the steps spread evenly over the millisecond;
* the PWM and direction pins drive the world's motors: the duty the world sees for
  a millisecond is the fraction of that millisecond the PWM pin was high (signed
  by the direction pin), as a motor averages it.

The gateware runs in board time locked to simulated time: `advance` runs the
clock cycles up to the simulator's ``now``, in short slices so an exchange never
waits long; an exchange takes the cycles its bits take (SCK = clk / 6, the
fastest rate the gateware takes). Real time needs the FPGA clock scaled down
(``sim.gateware_clk_hz``, default 1 MHz, i.e. 100x slower than the board's
100 MHz): docs/gateware.md has the measured speed.
"""

from __future__ import annotations

import logging
import threading
import time

from icefloe.config import Board
from icefloe.gateware.cxxsim import CompiledBoard
from icefloe.wire.icoboard import Descriptor, Peripherals, Wire, duty_to_raw

from .icoboard import Counters, LineHandles, Wheels

log = logging.getLogger("icefloe.sim.icoboard")

SCK_HALF_CYCLES = 3
"""SCK high and low for this many board clock cycles each (SCK = clk / 6, the fastest that works)."""
SLICE_CYCLES = 250
"""`advance` runs at most this many cycles at a time, then lets a waiting exchange in."""


class GatewareBoardModel(LineHandles):
    """The icoBoard gateware as a board model: `exchange` and `tick` like `IcoBoardModel`'s."""

    def __init__(self, world: Wheels, board: Board, *, clk_hz: float, seed: int = 0) -> None:
        super().__init__(seed)
        self.world = world
        self.wire = Wire.for_board(board)
        self.compiled = CompiledBoard(Peripherals.for_board(board), clk_hz=clk_hz, pwm_hz=board.pwm_hz)
        self.counters = Counters()
        self.last_frame = b""
        self.pwm = [0] * self.wire.actuators  # what each motor saw over the last millisecond
        self.running = False
        self._tripped = False
        self._pins = threading.Lock()      # the compiled board: one caller at a time
        self._waiting = 0                  # exchanges waiting for `_pins`

    # ------------------------------------------------------------------ test handles

    @property
    def forced_descriptor(self) -> Descriptor | None:
        return None

    @forced_descriptor.setter
    def forced_descriptor(self, value: Descriptor | None) -> None:
        if value is None:
            return  # "the truth": what the gateware says anyway
        raise ValueError("the gateware answers START from the peripheral list it was built for; "
                         "build it for another list ([board] sensors, actuators) instead")

    # ------------------------------------------------------------------ the board

    def exchange(self, frame: bytes, now: float) -> bytes:
        """One SPI exchange, clocked through the gateware's pins."""
        self.counters.frames += 1
        frame = self.last_frame = self._line_in(frame)
        self._waiting += 1  # `advance` lets us in before its next slice
        try:
            with self._pins:
                reply = self.compiled.exchange(frame, half=SCK_HALF_CYCLES)
        finally:
            self._waiting -= 1
        return self._line_out(reply)

    def advance(self, now: float) -> None:
        """Run the board's clock up to ``now`` (s of simulated time), the encoders moving there."""
        counts = self.world.counts()
        target = self.compiled.cycles(now)
        with self._pins:
            self.compiled.set_encoders(counts)
        while True:
            while self._waiting:
                time.sleep(0)  # a lock is not a queue: yield, or the next slice may win again
            with self._pins:
                left = target - self._board_cycles()
                if left <= 0:
                    return
                self.compiled.step(min(left, SLICE_CYCLES))

    def tick(self, now: float) -> None:
        """Called every simulated millisecond, after `advance`: the motors take the mean duty."""
        with self._pins:
            stats = self.compiled.read()
        self.counters.watchdog_trips += stats.trips
        if stats.trips:
            self._tripped = True
        elif self._tripped and stats.pwm == 0:  # report once the pins are seen low
            self._tripped = False
            after = (stats.last_high_cycle - stats.last_valid_cycle) / self.compiled.clk_hz
            log.warning("icoBoard gateware watchdog: PWM pins low %.3f ms after the last valid frame",
                        after * 1e3)
        self.counters.rejected += stats.frames_rejected
        self.running = stats.running
        self.pwm = [duty_to_raw(d) for d in stats.duty]
        self.world.set_duty(*self.duty)

    def _board_cycles(self) -> int:
        return self.compiled.total_cycles

    def close(self) -> None:
        with self._pins:
            self.compiled.close()
