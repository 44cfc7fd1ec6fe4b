"""The design on the icoBoard: `IcoBoardCore` with its ports on the platform's pins.

    IcoBoardPlatform(peripherals).build(IcoBoardTop(peripherals))   # what `icefloe gateware build` does
"""

from __future__ import annotations

from amaranth import Elaboratable, Module
from amaranth.lib.io import Buffer

from icefloe.wire.icoboard import Peripherals

from .core import PWM_HZ, IcoBoardCore
from .platform import IcoBoardPlatform


class IcoBoardTop(Elaboratable):
    """The board logic for ``peripherals`` at the icoBoard's 100 MHz, wired to the pins."""

    def __init__(self, peripherals: Peripherals | None = None, *, pwm_hz: float = PWM_HZ) -> None:
        self.peripherals = peripherals or Peripherals()
        self.pwm_hz = pwm_hz

    def elaborate(self, platform: IcoBoardPlatform) -> Module:
        m = Module()
        clock = platform.lookup(platform.default_clk).clock.frequency
        m.submodules.core = core = IcoBoardCore(self.peripherals, clk_hz=clock, pwm_hz=self.pwm_hz)

        spi = platform.request("pi_spi", 0, dir={"sck": "-", "cs_n": "-", "copi": "-", "cipo": "-"})
        m.submodules.sck = sck = Buffer("i", spi.sck)
        m.submodules.cs_n = cs_n = Buffer("i", spi.cs_n)
        m.submodules.copi = copi = Buffer("i", spi.copi)
        m.submodules.cipo = cipo = Buffer("o", spi.cipo)  # with an output enable: let go between frames
        m.d.comb += [core.sck.eq(sck.i), core.cs_n.eq(cs_n.i), core.copi.eq(copi.i),
                     cipo.o.eq(core.cipo), cipo.oe.eq(core.cipo_oe)]

        for i in range(max(len(self.peripherals.sensors), len(self.peripherals.actuators))):
            wheel = platform.request("wheel", i)
            if i < len(self.peripherals.actuators):
                m.d.comb += [wheel.pwm.o.eq(core.pwm[i]), wheel.dir.o.eq(core.dir[i])]
            if i < len(self.peripherals.sensors):
                m.d.comb += [core.enc_a[i].eq(wheel.a.i), core.enc_b[i].eq(wheel.b.i)]

        leds = [platform.request("led", i) for i in range(3)]
        m.d.comb += [leds[0].o.eq(core.running), leds[1].o.eq(core.watchdog), leds[2].o.eq(~core.cs_n)]
        return m
