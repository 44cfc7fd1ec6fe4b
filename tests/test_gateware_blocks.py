"""Each gateware block on its own, in Amaranth's simulator: quadrature, PWM, watchdog, SPI."""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from amaranth.sim import Simulator

from icefloe.errors import GatewareError
from icefloe.gateware.bench import phases, spi_exchange
from icefloe.gateware.core import check_peripherals
from icefloe.gateware.platform import pin_map_markdown
from icefloe.gateware.pwm import PwmOutput
from icefloe.gateware.quadrature import QuadratureDecoder
from icefloe.gateware.spi import SpiPeripheral
from icefloe.gateware.watchdog import Watchdog
from icefloe.wire.icoboard import Peripherals

FILTER = 8  # glitch filter, cycles


def _run(dut, bench, clk_hz: float = 100e6) -> None:
    sim = Simulator(dut)
    sim.add_clock(1 / clk_hz)
    sim.add_testbench(bench)
    sim.run()


def test_quadrature_counts_every_edge_both_ways_and_wraps_at_16_bits() -> None:
    dut = QuadratureDecoder(FILTER)

    async def bench(ctx) -> None:
        position = 0
        for target in (40, -25, 3):
            while position != target:
                position += 1 if target > position else -1
                ctx.set(dut.a, phases(position)[0])
                ctx.set(dut.b, phases(position)[1])
                await ctx.tick().repeat(FILTER + 3)  # the highest edge rate it takes: filter + 3 cycles
            assert ctx.get(dut.count) == position & 0xFFFF
        ctx.set(dut.clear, 1)
        await ctx.tick()
        ctx.set(dut.clear, 0)
        assert ctx.get(dut.count) == 0
        assert ctx.get(dut.errors) == 0

    _run(dut, bench)


def test_quadrature_counts_exactly_through_contact_bounce() -> None:
    dut = QuadratureDecoder(FILTER)
    rng = random.Random(7)

    async def bench(ctx) -> None:
        position = 0
        for _ in range(60):
            step = 1 if rng.random() < 0.7 else -1
            new = position + step
            a_new, b_new = phases(new)
            moving = "a" if phases(position)[0] != a_new else "b"
            pin, level = (dut.a, a_new) if moving == "a" else (dut.b, b_new)
            # The moving contact chatters: spikes shorter than the filter, and a few long
            # enough to pass it, before it settles at its new level.
            for _ in range(rng.randrange(1, 6)):
                ctx.set(pin, level)
                await ctx.tick().repeat(rng.choice([1, 2, FILTER - 1, FILTER + 3]))
                ctx.set(pin, 1 - level)
                await ctx.tick().repeat(rng.choice([1, 3, FILTER + 4]))
            ctx.set(pin, level)
            await ctx.tick().repeat(FILTER + 3)
            position = new
            assert ctx.get(dut.count) == position & 0xFFFF, position
        assert ctx.get(dut.errors) == 0

    _run(dut, bench)


def test_quadrature_ignores_spikes_and_counts_impossible_steps_as_errors() -> None:
    dut = QuadratureDecoder(FILTER)

    async def bench(ctx) -> None:
        ctx.set(dut.a, 1)
        await ctx.tick().repeat(FILTER - 1)   # a spike shorter than the filter: never seen
        ctx.set(dut.a, 0)
        await ctx.tick().repeat(2 * FILTER)
        assert ctx.get(dut.count) == 0
        ctx.set(dut.a, 1)
        ctx.set(dut.b, 1)                      # both phases at once: not a step
        await ctx.tick().repeat(2 * FILTER)
        assert (ctx.get(dut.count), ctx.get(dut.errors)) == (0, 1)

    _run(dut, bench)


@pytest.mark.parametrize(("duty", "high", "direction"), [(16384, 0.5, 0), (-8192, 0.25, 1), (32767, 1.0, 0),
                                                         (-32768, 1.0, 1), (0, 0.0, 0), (3277, 0.1, 0)])
def test_pwm_duty_and_direction_from_the_signed_value(duty: int, high: float, direction: int) -> None:
    dut = PwmOutput(clk_hz=10e6, pwm_hz=20e3)   # 500 steps per period
    assert dut.actual_hz == pytest.approx(20e3, rel=1e-3)

    async def bench(ctx) -> None:
        ctx.set(dut.duty, duty)
        await ctx.tick().until(dut.period_start)  # a new duty is taken at a period's start
        await ctx.tick()
        total = periods = 0
        async for _, _, pwm, start in ctx.tick().sample(dut.pwm, dut.period_start):
            total += pwm
            periods += start
            if periods == 4:
                break
        assert total / (4 * 500) == pytest.approx(high, abs=2 / 500)
        assert ctx.get(dut.dir) == direction

    _run(dut, bench, clk_hz=10e6)


def test_pwm_takes_a_new_duty_at_the_period_start_but_zero_at_once() -> None:
    dut = PwmOutput(clk_hz=10e6, pwm_hz=20e3)

    async def bench(ctx) -> None:
        ctx.set(dut.duty, 30000)
        await ctx.tick().until(dut.period_start)
        await ctx.tick().repeat(10)
        assert ctx.get(dut.pwm) == 1
        ctx.set(dut.duty, 1000)          # shorter pulse: not before this period has ended
        await ctx.tick().repeat(100)
        assert ctx.get(dut.pwm) == 1
        ctx.set(dut.duty, 0)             # stop: at once
        await ctx.tick().repeat(2)
        assert ctx.get(dut.pwm) == 0

    _run(dut, bench, clk_hz=10e6)


def test_watchdog_expires_after_exactly_its_cycles_unless_fed() -> None:
    dut = Watchdog(100)

    async def bench(ctx) -> None:
        await ctx.tick().repeat(99)
        assert not ctx.get(dut.expired)
        await ctx.tick()
        assert ctx.get(dut.expired)
        ctx.set(dut.feed, 1)
        await ctx.tick()
        ctx.set(dut.feed, 0)
        assert not ctx.get(dut.expired)

    _run(dut, bench)


def test_spi_peripheral_shifts_bytes_both_ways_in_mode_0() -> None:
    dut = SpiPeripheral()
    sent, answer = b"\x5a\xc3\x00\xff", b"\x01\x80\x7e\xa5"
    received = []

    async def engine(ctx) -> None:
        # Like the protocol engine: the next byte is ready before the peripheral takes it.
        queue = [*answer[1:], 0, 0]
        ctx.set(dut.tx_data, answer[0])
        async for _, _, load, valid, data in ctx.tick().sample(dut.tx_load, dut.rx_valid, dut.rx_data):
            if valid:
                received.append(data)
            if load:
                ctx.set(dut.tx_data, queue.pop(0))

    async def bench(ctx) -> None:
        assert await spi_exchange(ctx, dut, sent, sck_hz=10e6) == answer
        assert bytes(received) == sent
        assert not ctx.get(dut.cipo_oe) and not ctx.get(dut.cipo)  # CIPO let go between frames

    sim = Simulator(dut)
    sim.add_clock(1e-8)
    sim.add_testbench(engine, background=True)
    sim.add_testbench(bench)
    sim.run()


def test_the_gateware_builds_encoders_and_pwm_only() -> None:
    check_peripherals(Peripherals.of(3, 1))
    with pytest.raises(GatewareError, match=r"1\.\.8 sensors"):
        check_peripherals(Peripherals.of(9, 2))
    with pytest.raises(GatewareError, match=r"kind 'pwm' only, not \['servo'\]"):
        check_peripherals(Peripherals(("encoder",), ("pwm", "servo")))


def test_the_documented_pin_map_is_the_platforms() -> None:
    docs = (Path(__file__).resolve().parent.parent / "docs" / "gateware.md").read_text()
    assert pin_map_markdown() in docs, "docs/gateware.md: paste `icefloe gateware pins` again"
