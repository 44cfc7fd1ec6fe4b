"""The whole board logic: SPI + protocol engine + watchdog + one block per peripheral.

`IcoBoardCore` has the FPGA's pins as plain ports (vectors of M encoder phases,
N PWM and direction outputs), so the same design runs in Amaranth's simulator,
in the compiled simulation (`icefloe.gateware.cxxsim`) and, wrapped by
`icefloe.gateware.top.IcoBoardTop`, on the icoBoard.

Everything is built from the peripheral list (`icefloe.wire.icoboard.Peripherals`)
and the clock: one `QuadratureDecoder` per ``"encoder"``, one `PwmOutput` per
``"pwm"``, the 50 ms watchdog in cycles of ``clk_hz``. The same list gives the
START descriptor hwbridge checks, so a board built for another list is refused.
"""

from __future__ import annotations

from amaranth import Module
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from icefloe.errors import GatewareError
from icefloe.wire.icoboard import WATCHDOG_S, Peripherals

from .protocol import ProtocolEngine
from .pwm import PwmOutput
from .quadrature import QuadratureDecoder
from .spi import SpiPeripheral
from .watchdog import Watchdog

CLK_HZ = 100e6
"""The icoBoard's oscillator (pin R9), Hz."""
PWM_HZ = 20e3
"""Default motor PWM frequency, Hz (above hearing; the config's ``board.pwm_hz``)."""
FILTER_S = 1e-6
"""Encoder glitch filter: a phase must hold this long to count, s (edges come >= 0.3 ms apart)."""
MAX_PERIPHERALS = 8
"""Encoders and motor outputs each: 8 six-pin PMOD ports (`icefloe.gateware.pins`)."""


def check_peripherals(peripherals: Peripherals) -> None:
    """Raise `GatewareError` unless this gateware can build the list (1..8 encoders, 1..8 PWM)."""
    for what, kinds, kind in (("sensors", peripherals.sensors, "encoder"),
                              ("actuators", peripherals.actuators, "pwm")):
        if not 1 <= len(kinds) <= MAX_PERIPHERALS:
            raise GatewareError(f"the gateware builds 1..{MAX_PERIPHERALS} {what}, "
                                f"the peripheral list has {len(kinds)}")
        others = sorted(set(kinds) - {kind})
        if others:
            raise GatewareError(f"the gateware builds {what} of kind {kind!r} only, not {others}")


class IcoBoardCore(wiring.Component):
    """The board logic for ``peripherals`` at ``clk_hz``, with PWM at ``pwm_hz``."""

    def __init__(self, peripherals: Peripherals | None = None, *, clk_hz: float = CLK_HZ,
                 pwm_hz: float = PWM_HZ, filter_s: float = FILTER_S) -> None:
        peripherals = peripherals or Peripherals()
        check_peripherals(peripherals)
        self.peripherals = peripherals
        self.clk_hz = clk_hz
        self.pwm_hz = pwm_hz
        self.filter_cycles = max(1, round(clk_hz * filter_s))
        self.watchdog_cycles = round(clk_hz * WATCHDOG_S)
        m, n = len(peripherals.sensors), len(peripherals.actuators)
        super().__init__({
            "sck": In(1), "cs_n": In(1, init=1), "copi": In(1), "cipo": Out(1), "cipo_oe": Out(1),
            "enc_a": In(m), "enc_b": In(m), "pwm": Out(n), "dir": Out(n),
            # not pins: what the board is doing, for LEDs, tests and the simulation
            "running": Out(1), "watchdog": Out(1),
            "frame_valid": Out(1), "frame_rejected": Out(1), "tripped": Out(1),
            "pwm_period_start": Out(1),
        })

    def elaborate(self, platform: object) -> Module:
        m = Module()
        m.submodules.spi = spi = SpiPeripheral()
        m.submodules.engine = engine = ProtocolEngine(self.peripherals)
        m.submodules.watchdog = watchdog = Watchdog(self.watchdog_cycles)
        m.d.comb += [
            spi.sck.eq(self.sck), spi.cs_n.eq(self.cs_n), spi.copi.eq(self.copi),
            self.cipo.eq(spi.cipo), self.cipo_oe.eq(spi.cipo_oe),
            engine.start.eq(spi.start), engine.end.eq(spi.end), engine.rx_data.eq(spi.rx_data),
            engine.rx_valid.eq(spi.rx_valid), engine.partial.eq(spi.partial),
            engine.tx_load.eq(spi.tx_load), spi.tx_data.eq(engine.tx_data),
            watchdog.feed.eq(engine.feed), engine.expired.eq(watchdog.expired),
            self.running.eq(engine.running), self.watchdog.eq(engine.watchdog),
            self.frame_valid.eq(engine.frame_valid), self.frame_rejected.eq(engine.frame_rejected),
            self.tripped.eq(engine.tripped),
        ]
        for i in range(len(self.peripherals.sensors)):
            decoder = QuadratureDecoder(self.filter_cycles)
            m.submodules[f"encoder{i}"] = decoder
            m.d.comb += [decoder.a.eq(self.enc_a[i]), decoder.b.eq(self.enc_b[i]),
                         decoder.clear.eq(engine.clear_counts), engine.counts[i].eq(decoder.count)]
        for i in range(len(self.peripherals.actuators)):
            pwm = PwmOutput(self.clk_hz, self.pwm_hz)
            m.submodules[f"pwm{i}"] = pwm
            m.d.comb += [pwm.duty.eq(engine.duties[i]), self.pwm[i].eq(pwm.pwm), self.dir[i].eq(pwm.dir)]
            if i == 0:
                m.d.comb += self.pwm_period_start.eq(pwm.period_start)
        return m
