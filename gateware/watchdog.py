"""The board-side watchdog: ``expired`` once ``cycles`` clock cycles pass without a ``feed``.

The protocol engine feeds it with every valid frame and, when it expires while
the board runs with a non-zero duty, zeroes every PWM output (protocol v2: no
valid frame for 50 ms -> the wheels stop, even if the Pi's process died).
"""

# No `from __future__ import annotations` here: wiring.Component reads its signature from
# the class annotations, which must stay objects, not strings.
from amaranth import Module, Signal
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out


class Watchdog(wiring.Component):
    feed: In(1)
    expired: Out(1)

    def __init__(self, cycles: int) -> None:
        if cycles < 1:
            raise ValueError(f"watchdog needs at least 1 cycle, got {cycles}")
        self.cycles = cycles
        super().__init__()

    def elaborate(self, platform: object) -> Module:
        m = Module()
        elapsed = Signal(range(self.cycles + 1))
        with m.If(self.feed):
            m.d.sync += elapsed.eq(0)
        with m.Elif(elapsed != self.cycles):
            m.d.sync += elapsed.eq(elapsed + 1)
        m.d.comb += self.expired.eq(elapsed == self.cycles)
        return m
