"""The gateware's protocol engine, bit by bit in Amaranth's simulator, against the shared vectors.

Every frame of tests/icoboard_vectors.py is clocked into `IcoBoardCore`'s SPI
pins one bit at a time (the host's own bytes), the encoder phases are moved as
a wheel moves them, and the PWM and direction pins are averaged as a motor
does. The design is the board's, at a 1 MHz clock instead of 100 MHz so that a
50 ms watchdog fits in a second of Python simulation; tests/test_gateware_cxxsim.py
runs the same vectors at 100 MHz, compiled.
"""

from __future__ import annotations

import pytest
from amaranth.sim import Simulator
from icoboard_vectors import DUTY_TOLERANCE, SCENARIOS, Duty, Move, Send, Trips, Wait

from icefloe.gateware.bench import phases, spi_exchange
from icefloe.gateware.core import IcoBoardCore

pytestmark = pytest.mark.timeout(600)  # ~10 s of Python simulation on a quiet machine, 80 s seen on a busy one

CLK_HZ = 1e6
SCK_HZ = CLK_HZ / 8
PWM_HZ = 2e3
"""500 clock cycles per PWM period, as many duty steps as the board's 100 MHz / 20 kHz has per 10."""


async def _mean_duties(ctx, core, cycles: int) -> tuple[float, float]:
    """The signed mean of PWM outputs 0 and 1 over ``cycles`` cycles, as the motors see it."""
    total = [0, 0]
    seen = 0
    async for _, _, pwm, direction in ctx.tick().sample(core.pwm, core.dir):
        for channel in (0, 1):
            if pwm >> channel & 1:
                total[channel] += -1 if direction >> channel & 1 else 1
        seen += 1
        if seen == cycles:
            return total[0] / cycles, total[1] / cycles
    raise AssertionError("the simulation ended")


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_the_gateware_meets_the_shared_vectors(name: str) -> None:
    core = IcoBoardCore(clk_hz=CLK_HZ, pwm_hz=PWM_HZ)
    sim = Simulator(core)
    sim.add_clock(1 / CLK_HZ)
    trips = [0]
    checked = []

    async def count_trips(ctx) -> None:
        async for _ in ctx.posedge(core.watchdog):  # the WATCHDOG status bit: set by each trip
            trips[0] += 1

    async def host(ctx) -> None:
        position = [0, 0]
        duty = None  # the mean duty over the last millisecond of the last Wait
        for step in SCENARIOS[name]:
            match step:
                case Send():
                    reply = await spi_exchange(ctx, core, step.request, sck_hz=SCK_HZ)
                    assert reply[0] == step.status, (step, reply.hex(" "))
                    assert step.reply is None or reply == step.reply, (step, reply.hex(" "))
                case Move():
                    # one phase step at a time, each held longer than the glitch filter
                    for i, target in enumerate((step.left, step.right)):
                        while position[i] != target:
                            position[i] += 1 if target > position[i] else -1
                            a, b = phases(position[i])
                            ctx.set(core.enc_a[i], a)
                            ctx.set(core.enc_b[i], b)
                            await ctx.tick().repeat(core.filter_cycles + 3)
                case Wait():
                    await ctx.delay((step.ms - 1) * 1e-3)
                    duty = await _mean_duties(ctx, core, round(CLK_HZ / 1000))  # 1 ms: 2 PWM periods
                case Duty():
                    assert duty == pytest.approx((step.left, step.right), abs=DUTY_TOLERANCE), step
                case Trips():
                    assert trips[0] == step.count, step
            checked.append(step)

    sim.add_testbench(count_trips, background=True)
    sim.add_testbench(host)
    sim.run()
    assert checked == list(SCENARIOS[name])
