"""SPI peripheral, mode 0, oversampled in the system clock domain.

The Pi is the SPI controller: it drives chip select (active low), the clock
SCK and the data line COPI; we drive CIPO. In mode 0 (CPOL = 0, CPHA = 0, what
hwbridge's `SpiTransport` sets) both sides sample on the rising edge of SCK.

SCK, CS and COPI are not clocks here: each goes through a two-flop synchronizer
into the 100 MHz system clock domain, and the edges are found by comparing the
synchronized value with the one a cycle before. So SCK must stay high and low
for at least two system clock cycles, and the design has one clock domain.

We change CIPO just *after* the rising edge we sampled on (2-3 cycles later,
once the synchronizer has shown it), not at the falling edge: the controller
has already sampled, and the next bit then has almost a whole SCK period to
reach the controller before it samples again. That is what sets the highest SCK
(docs/gateware.md; measured in `tests/test_gateware_cxxsim.py`).

Byte 0 is loaded at the falling edge of CS, also 2-3 cycles late; its first bit
must be on CIPO before the first rising edge of SCK. The protocol makes that
free: byte 0 is the status byte, whose top bit is always 0, and CIPO is 0
while CS is high.

Interface to the protocol engine, all in the system clock domain:

* ``start`` / ``end``: one-cycle strobes at the falling / rising edge of CS.
* ``rx_valid``: one-cycle strobe when a byte is complete, the byte on ``rx_data``.
* ``tx_load``: one-cycle strobe when ``tx_data`` is taken as the next byte to send:
  at ``start`` (byte 0) and with every ``rx_valid`` (the byte after it).
* ``partial``: some bits of a byte have arrived since the last whole byte.
"""

# No `from __future__ import annotations` here: wiring.Component reads its signature from
# the class annotations, which must stay objects, not strings.
from amaranth import Cat, Module, Signal
from amaranth.lib import wiring
from amaranth.lib.cdc import FFSynchronizer
from amaranth.lib.wiring import In, Out


class SpiPeripheral(wiring.Component):
    """The pins on one side, bytes and strobes on the other (module docstring)."""

    sck: In(1)
    cs_n: In(1, init=1)
    copi: In(1)
    cipo: Out(1)
    cipo_oe: Out(1)
    """Drive CIPO only while selected (the line is shared with the configuration flash)."""

    start: Out(1)
    end: Out(1)
    rx_data: Out(8)
    rx_valid: Out(1)
    partial: Out(1)
    tx_data: In(8)
    tx_load: Out(1)

    def elaborate(self, platform: object) -> Module:
        m = Module()
        sck, cs_n, copi = Signal(), Signal(init=1), Signal()
        m.submodules.sync_sck = FFSynchronizer(self.sck, sck)
        m.submodules.sync_cs = FFSynchronizer(self.cs_n, cs_n, init=1)
        m.submodules.sync_copi = FFSynchronizer(self.copi, copi)

        sck_was, cs_was = Signal(), Signal(init=1)
        m.d.sync += [sck_was.eq(sck), cs_was.eq(cs_n)]
        rising = sck & ~sck_was
        selected = ~cs_n

        bits = Signal(3)            # bits of the current byte received so far
        shift_in = Signal(7)        # those bits, MSB first
        shift_out = Signal(8)       # CIPO is its top bit

        m.d.comb += [
            self.start.eq(cs_was & ~cs_n),
            self.end.eq(~cs_was & cs_n),
            self.rx_data.eq(Cat(copi, shift_in)),
            self.partial.eq(bits != 0),
            self.cipo.eq(shift_out[7]),
            self.cipo_oe.eq(selected),
        ]
        with m.If(self.start):
            m.d.comb += self.tx_load.eq(1)
            m.d.sync += [shift_out.eq(self.tx_data), bits.eq(0)]
        with m.Elif(selected & rising):
            m.d.sync += [shift_in.eq(Cat(copi, shift_in[:6])), bits.eq(bits + 1)]
            with m.If(bits == 7):
                m.d.comb += [self.rx_valid.eq(1), self.tx_load.eq(1)]
                m.d.sync += shift_out.eq(self.tx_data)
            with m.Else():
                m.d.sync += shift_out.eq(shift_out << 1)
        with m.Elif(~selected):
            m.d.sync += [shift_out.eq(0), bits.eq(0)]
        return m
