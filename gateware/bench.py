"""Test benches for Amaranth's simulator: the Pi's side of the pins, bit by bit.

    sim = Simulator(core); sim.add_clock(1 / core.clk_hz)
    async def bench(ctx):
        reply = await spi_exchange(ctx, core, wire.request(Op.START, seq=1), sck_hz=10e6)
    sim.add_testbench(bench); sim.run()

`spi_exchange` is an SPI mode 0 controller in simulated time (like the Pi's:
it sets COPI after each falling edge and samples CIPO at each rising edge,
``setup_s`` early to stand for pad delays and the controller's setup time).
`quadrature_steps` moves an encoder's two phases as a turning wheel does.
"""

from __future__ import annotations

from typing import Any

QUADRATURE = ((0, 0), (1, 0), (1, 1), (0, 1))
"""(A, B) for counts 0, 1, 2, 3 mod 4: going forward, A leads B."""


def phases(count: int) -> tuple[int, int]:
    """The (A, B) levels of an encoder that has moved ``count`` steps from (0, 0)."""
    return QUADRATURE[count % 4]


async def spi_exchange(ctx: Any, pins: Any, frame: bytes, *, sck_hz: float, setup_s: float = 0.0,
                       lead_s: float | None = None, gap_s: float | None = None) -> bytes:
    """One full-duplex exchange of ``frame`` on ``pins`` (sck, cs_n, copi, cipo); the bytes read.

    ``lead_s``: CS low to the first rising edge (default half an SCK period);
    ``gap_s``: CS high after the exchange (default one SCK period).
    """
    half = 0.5 / sck_hz
    if not 0 <= setup_s < half:
        raise ValueError(f"setup {setup_s} s must be shorter than half an SCK period ({half} s)")
    ctx.set(pins.cs_n, 0)
    reply = bytearray()
    first = True
    for byte in frame:
        got = 0
        for bit in range(7, -1, -1):
            ctx.set(pins.copi, byte >> bit & 1)
            wait = (half if lead_s is None else lead_s) if first else half
            first = False
            await ctx.delay(wait - setup_s)
            got = got << 1 | ctx.get(pins.cipo)
            await ctx.delay(setup_s)
            ctx.set(pins.sck, 1)
            await ctx.delay(half)
            ctx.set(pins.sck, 0)
        reply.append(got)
    await ctx.delay(half)
    ctx.set(pins.cs_n, 1)
    await ctx.delay(2 * half if gap_s is None else gap_s)
    return bytes(reply)


async def quadrature_steps(ctx: Any, a: Any, b: Any, start: int, steps: int, *, every_s: float) -> int:
    """Move an encoder from count ``start`` by ``steps`` (signed), one step every ``every_s``."""
    count = start
    for _ in range(abs(steps)):
        count += 1 if steps > 0 else -1
        level_a, level_b = phases(count)
        ctx.set(a, level_a)
        ctx.set(b, level_b)
        await ctx.delay(every_s)
    return count
