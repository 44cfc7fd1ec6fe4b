"""The protocol v2 engine: the board side of `icefloe.wire.icoboard`, in gateware.

It sits between the SPI peripheral (bytes and strobes) and the peripherals
(encoder counts in, duties out). Frame by frame, exactly as the wire module
documents it:

* At the falling edge of CS it latches every encoder count (the snapshot this
  exchange returns: same-period sampling) and starts sending byte 0, the status
  (RUNNING, WATCHDOG, REJECTED), then byte 1, the ack (seq of the last valid
  frame). From byte 2 on the reply depends on the opcode, which has arrived by
  then: START's descriptor (M, N, B, hash), RECEIVE/TRANSMIT's counts, and the
  CRC-8 of the reply at the position the opcode's length gives; zeros after it.
* At the rising edge of CS it checks what came in: a known opcode, exactly the
  opcode's length in whole bytes, the CRC-8, and no RECEIVE/TRANSMIT before
  START. A bad frame changes nothing but the REJECTED bit of the next reply. A
  valid frame feeds the watchdog, becomes the next ack, and acts: START runs,
  TRANSMIT sets the duties (and clears WATCHDOG), EXIT zeroes the duties and
  stops, RESET zeroes the duties and the encoder counters.
* When the watchdog expires while running with any non-zero duty, every duty
  goes to 0 and the WATCHDOG bit is set.

The reply bytes are worked out one byte ahead: the SPI peripheral takes the
next byte the moment the previous one is complete, so the byte after the
opcode (the ack) is the only one that cannot depend on it, and does not. Each
byte is ready in a register a cycle after the previous one was taken, and the
frame's verdict a cycle after its last byte: what meets 100 MHz on the iCE40.
"""

from __future__ import annotations

from functools import reduce
from operator import xor

from amaranth import Cat, Const, Module, Mux, Signal, signed
from amaranth.hdl import Value
from amaranth.lib import data, wiring
from amaranth.lib.wiring import In, Out

from icefloe.wire.icoboard import HEADER_V2, START_LENGTH_V2, WIDTH, Op, Peripherals, Status

CRC8_POLY = 0x2F
"""CRC-8/AUTOSAR: poly 0x2F, init 0xFF, xorout 0xFF (`icefloe.wire.icoboard.crc8`)."""


def _crc8_column(bit: int) -> int:
    reg = 1 << bit
    for _ in range(8):
        reg = ((reg << 1) ^ CRC8_POLY) & 0xFF if reg & 0x80 else (reg << 1) & 0xFF
    return reg


_COLUMNS = [_crc8_column(bit) for bit in range(8)]


def crc8_update(crc: Value, byte: Value) -> Value:
    """The CRC-8 register after one more byte: one XOR network, no loop (CRC is linear)."""
    x = crc ^ byte
    bits = []
    for out in range(8):
        terms = [x[i] for i in range(8) if _COLUMNS[i] >> out & 1]
        bits.append(reduce(xor, terms) if terms else Const(0, 1))
    return Cat(*bits)


class ProtocolEngine(wiring.Component):
    """Protocol v2 for the board shape ``peripherals`` (M encoders, N PWM outputs)."""

    def __init__(self, peripherals: Peripherals) -> None:
        self.peripherals = peripherals
        self.m = len(peripherals.sensors)
        self.n = len(peripherals.actuators)
        self.slots = max(self.m, self.n)
        super().__init__({
            # from / to the SPI peripheral
            "start": In(1), "end": In(1), "rx_data": In(8), "rx_valid": In(1), "partial": In(1),
            "tx_load": In(1), "tx_data": Out(8),
            # from / to the peripherals and the watchdog
            "counts": In(data.ArrayLayout(16, self.m)),
            "duties": Out(data.ArrayLayout(signed(16), self.n)),
            "clear_counts": Out(1),
            "feed": Out(1),
            "expired": In(1),
            # state, and strobes for tests and the simulation
            "running": Out(1), "watchdog": Out(1),
            "frame_valid": Out(1), "frame_rejected": Out(1), "tripped": Out(1),
        })

    def length(self, op: Op) -> int:
        """Bytes in one exchange of ``op`` (as `icefloe.wire.icoboard.Wire.length`, v2)."""
        values = {Op.RECEIVE: self.m, Op.TRANSMIT: self.slots}.get(op, 0)
        return START_LENGTH_V2 if op == Op.START else HEADER_V2 + WIDTH * values + 1

    def elaborate(self, platform: object) -> Module:
        m = Module()
        descriptor = self.peripherals.descriptor
        start_body = [descriptor.sensors, descriptor.actuators, descriptor.width,
                      *descriptor.hash.to_bytes(4, "big")]

        rejected = Signal()
        last_seq = Signal(8)
        op, seq = Signal(8), Signal(8)
        count = Signal(6)                      # bytes received in this frame (saturating)
        crc_rx, crc_before_last, last_byte = Signal(8, init=0xFF), Signal(8), Signal(8)
        crc_tx = Signal(8, init=0xFF)
        snapshot = [Signal(16, name=f"snapshot{i}") for i in range(self.m)]
        incoming = [Signal(8, name=f"incoming{i}") for i in range(WIDTH * self.n)]
        selected = Signal()
        m.d.sync += selected.eq(Mux(self.start, 1, Mux(self.end, 0, selected)))

        # Registered a cycle after what they depend on, to keep the logic between two
        # flip-flops short enough for 100 MHz: there is a whole byte time to spare.
        length = Signal(6)                     # bytes in an exchange of `op`
        with m.Switch(op):
            for code in Op:
                with m.Case(code):
                    m.d.sync += length.eq(self.length(code))
            with m.Default():
                m.d.sync += length.eq(self.length(Op.EMPTY))
        is_counts = Signal()
        m.d.sync += is_counts.eq((op == Op.RECEIVE) | (op == Op.TRANSMIT))

        # ---------------------------------------------------------------- reply, one byte ahead
        # `tx_next` is the byte the SPI peripheral takes at its next `tx_load`: the status while
        # CS is high, then each next byte, worked out in the cycles after the previous load.
        tx_next, next_index = Signal(8), Signal(6)
        status = Cat(self.running, self.watchdog, rejected)
        assert (Status.RUNNING, Status.WATCHDOG, Status.REJECTED) == (1, 2, 4)
        body = Signal(8)
        with m.Switch(next_index):
            for j in range(max(len(start_body), WIDTH * self.slots)):
                with m.Case(HEADER_V2 + j):
                    from_start = start_body[j] if j < len(start_body) else 0
                    from_counts = snapshot[j // 2].word_select(1 - j % 2, 8) if j < WIDTH * self.m else 0
                    m.d.comb += body.eq(Mux(op == Op.START, from_start, Mux(is_counts, from_counts, 0)))
        reply = Mux(next_index == 1, last_seq,
                    Mux(next_index == length - 1, crc_tx ^ 0xFF,
                        Mux(next_index >= length, 0, body)))
        m.d.comb += self.tx_data.eq(tx_next)
        with m.If(self.tx_load):
            m.d.sync += next_index.eq(next_index + 1)
            with m.If(next_index < length - 1):
                m.d.sync += crc_tx.eq(crc8_update(Mux(self.start, 0xFF, crc_tx), tx_next))
        with m.Elif(selected):
            m.d.sync += tx_next.eq(reply)
        with m.Else():
            m.d.sync += [tx_next.eq(status), next_index.eq(0)]

        # ---------------------------------------------------------------- the frame coming in
        with m.If(self.start):
            m.d.sync += [count.eq(0), crc_rx.eq(0xFF), rejected.eq(0)]
            m.d.sync += [snap.eq(self.counts[i]) for i, snap in enumerate(snapshot)]
        with m.Elif(self.rx_valid):
            m.d.sync += [count.eq(Mux(count.all(), count, count + 1)),
                         crc_before_last.eq(crc_rx), crc_rx.eq(crc8_update(crc_rx, self.rx_data)),
                         last_byte.eq(self.rx_data)]
            with m.Switch(count):
                with m.Case(0):
                    m.d.sync += op.eq(self.rx_data)
                with m.Case(1):
                    m.d.sync += seq.eq(self.rx_data)
                for k, byte in enumerate(incoming):
                    with m.Case(HEADER_V2 + k):
                        m.d.sync += byte.eq(self.rx_data)
        # Is what has come in so far a valid frame? Ready long before CS rises.
        frame_ok = Signal()
        m.d.sync += frame_ok.eq((op <= max(Op)) & (count == length) & ~self.partial
                                & (last_byte == (crc_before_last ^ 0xFF)) & (~is_counts | self.running))

        # ---------------------------------------------------------------- the watchdog
        any_duty = Signal()
        m.d.sync += any_duty.eq(Cat(*[self.duties[i] != 0 for i in range(self.n)]).any())
        with m.If(self.expired & self.running & any_duty):
            m.d.comb += self.tripped.eq(1)
            m.d.sync += [self.duties[i].eq(0) for i in range(self.n)]
            m.d.sync += [self.watchdog.eq(1), any_duty.eq(0)]  # one trip, not one per cycle

        # ---------------------------------------------------------------- the frame ends
        m.d.sync += self.clear_counts.eq(0)
        with m.If(self.end):
            with m.If(frame_ok):
                m.d.comb += [self.frame_valid.eq(1), self.feed.eq(1)]
                m.d.sync += last_seq.eq(seq)
                with m.Switch(op):
                    with m.Case(Op.START):
                        m.d.sync += self.running.eq(1)
                    with m.Case(Op.TRANSMIT):
                        m.d.sync += self.watchdog.eq(0)
                        m.d.sync += [self.duties[i].eq(Cat(incoming[2 * i + 1], incoming[2 * i]))
                                     for i in range(self.n)]
                    with m.Case(Op.EXIT):
                        m.d.sync += self.running.eq(0)
                        m.d.sync += [self.duties[i].eq(0) for i in range(self.n)]
                    with m.Case(Op.RESET):
                        m.d.sync += self.clear_counts.eq(1)
                        m.d.sync += [self.duties[i].eq(0) for i in range(self.n)]
            with m.Else():
                m.d.comb += self.frame_rejected.eq(1)
                m.d.sync += rejected.eq(1)
        return m
