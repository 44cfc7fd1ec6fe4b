"""Quadrature decoder: two encoder phases in, a 16-bit wrapping count out (x4).

An incremental encoder gives two square waves A and B a quarter period apart.
Going forward the pair steps 00 -> 10 -> 11 -> 01 -> 00 (A leads B), backward
the other way. We count every step, i.e. every edge of A and of B: four counts
per encoder line ("x4"), so a robot config's ``ticks_per_rev`` is four times
the encoder's lines per wheel turn (docs/gateware.md).

Each phase goes through a two-flop synchronizer and a glitch filter: a new level
is taken only once it has been stable for ``filter_cycles`` system clock cycles,
so spikes shorter than that are not seen at all. Contact bounce that outlasts
the filter is seen as a step back and forth (+1 -1 +1 ...), which a quadrature
count nets out exactly: bounce on one phase while the other is steady can never
move the count by more than one. A step where both phases change at once is
impossible for a real encoder (the edges are a quarter period apart); it is
counted in ``errors`` and ignored.

The highest edge rate decoded exactly is one edge every ``filter_cycles + 1``
cycles per phase; the motors produce about 1300 counts/s (sim/world.py), i.e.
an edge every 0.8 ms.
"""

# No `from __future__ import annotations` here: wiring.Component reads its signature from
# the class annotations, which must stay objects, not strings.
from amaranth import Module, Signal
from amaranth.lib import wiring
from amaranth.lib.cdc import FFSynchronizer
from amaranth.lib.wiring import In, Out


class GlitchFilter(wiring.Component):
    """A level that must hold for ``cycles`` clock cycles before ``output`` follows it."""

    input: In(1)
    output: Out(1)

    def __init__(self, cycles: int) -> None:
        if cycles < 1:
            raise ValueError(f"glitch filter needs at least 1 cycle, got {cycles}")
        self.cycles = cycles
        super().__init__()

    def elaborate(self, platform: object) -> Module:
        m = Module()
        held = Signal(range(self.cycles + 1))
        with m.If(self.input == self.output):
            m.d.sync += held.eq(0)
        with m.Elif(held == self.cycles - 1):
            m.d.sync += [self.output.eq(self.input), held.eq(0)]
        with m.Else():
            m.d.sync += held.eq(held + 1)
        return m


class QuadratureDecoder(wiring.Component):
    """Phases ``a``, ``b`` (raw pins) -> ``count`` (16 bits, wrapping); ``clear`` zeroes it."""

    a: In(1)
    b: In(1)
    clear: In(1)
    count: Out(16)
    errors: Out(8)
    """Steps where both phases changed at once (saturating)."""

    def __init__(self, filter_cycles: int) -> None:
        self.filter_cycles = filter_cycles
        super().__init__()

    def elaborate(self, platform: object) -> Module:
        m = Module()
        a_sync, b_sync = Signal(), Signal()
        m.submodules.sync_a = FFSynchronizer(self.a, a_sync)
        m.submodules.sync_b = FFSynchronizer(self.b, b_sync)
        m.submodules.filter_a = filter_a = GlitchFilter(self.filter_cycles)
        m.submodules.filter_b = filter_b = GlitchFilter(self.filter_cycles)
        m.d.comb += [filter_a.input.eq(a_sync), filter_b.input.eq(b_sync)]
        a, b = filter_a.output, filter_b.output

        a_was, b_was = Signal(), Signal()
        m.d.sync += [a_was.eq(a), b_was.eq(b)]
        a_moved, b_moved = a != a_was, b != b_was
        # Forward (00 -> 10 -> 11 -> 01) is exactly when the new A differs from the old B.
        forward = a ^ b_was
        with m.If(self.clear):
            m.d.sync += self.count.eq(0)
        with m.Elif(a_moved & b_moved):
            with m.If(self.errors != 0xFF):
                m.d.sync += self.errors.eq(self.errors + 1)
        with m.Elif(a_moved | b_moved):
            with m.If(forward):
                m.d.sync += self.count.eq(self.count + 1)
            with m.Else():
                m.d.sync += self.count.eq(self.count - 1)
        return m
