"""PWM + direction output for one motor driver (e.g. a Digilent Pmod HB5: DIR and EN).

``duty`` is the protocol's raw signed 16-bit value: sign = direction (``dir``
high = negative = backward), magnitude 32767 = 100 % (-32768 counts as -32767).

The period comes from a phase accumulator, not a divider: every clock cycle the
phase advances by ``increment`` = 2^width * pwm_hz / clk_hz, and ``pwm`` is high
while the top 15 bits of the phase are below the duty magnitude. So the duty
needs no multiplier (the iCE40 has none) and any frequency is possible; the
frequency error is under 0.1 % and the duty has clk_hz / pwm_hz steps per period
(5000 at 100 MHz and 20 kHz).

A new duty is taken at the start of a period, so no pulse is ever cut or
stretched by an update; a duty of 0 is taken at once (stopping never waits).
"""

# No `from __future__ import annotations` here: wiring.Component reads its signature from
# the class annotations, which must stay objects, not strings.
import math

from amaranth import Module, Mux, Signal, signed
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

DUTY_BITS = 15
"""Magnitude bits of the duty (32767 = 100 %)."""
DUTY_FULL = (1 << DUTY_BITS) - 1


class PwmOutput(wiring.Component):
    duty: In(signed(16))
    pwm: Out(1)
    dir: Out(1)
    period_start: Out(1)
    """One-cycle strobe at the start of every PWM period (for tests and the simulation)."""

    def __init__(self, clk_hz: float, pwm_hz: float) -> None:
        if not 0 < pwm_hz <= clk_hz / 2:
            raise ValueError(f"PWM frequency {pwm_hz} Hz must be in (0, clk/2 = {clk_hz / 2} Hz]")
        self.clk_hz = clk_hz
        self.pwm_hz = pwm_hz
        # Enough fraction bits that the increment has >= 500 steps: frequency error < 0.1 %.
        exact = pwm_hz / clk_hz * (1 << DUTY_BITS)
        self.fraction_bits = max(0, math.ceil(math.log2(500 / exact)))
        self.width = DUTY_BITS + self.fraction_bits
        self.increment = round(pwm_hz / clk_hz * (1 << self.width))
        super().__init__()

    @property
    def actual_hz(self) -> float:
        """The frequency the accumulator really produces, Hz."""
        return self.increment * self.clk_hz / (1 << self.width)

    def elaborate(self, platform: object) -> Module:
        m = Module()
        phase = Signal(self.width)
        wrapped = Signal()
        m.d.sync += [phase.eq(phase + self.increment), wrapped.eq(phase + self.increment >= (1 << self.width))]
        m.d.comb += self.period_start.eq(wrapped)

        magnitude = Signal(DUTY_BITS)
        negative = self.duty < 0
        absolute = Mux(negative, -self.duty, self.duty)           # 0 .. 32768
        m.d.comb += magnitude.eq(Mux(absolute > DUTY_FULL, DUTY_FULL, absolute))

        applied = Signal(DUTY_BITS)
        with m.If(self.duty == 0):
            m.d.sync += applied.eq(0)
        with m.Elif(wrapped):
            m.d.sync += [applied.eq(magnitude), self.dir.eq(negative)]
        on = (applied == DUTY_FULL) | (phase[self.fraction_bits:] < applied)
        m.d.sync += self.pwm.eq(on)
        return m
