"""Gateware in the loop: what one simulated millisecond of the icoBoard costs, next to the Python model.

    .venv/bin/python bench/gateware_sim.py [--seconds 2]

For each board model, in the same run and the same process, the simulator's
per-millisecond work without the bus: the world steps 1 ms, the board ticks,
and one TRANSMIT frame (what hwbridge sends every period) is exchanged. Printed:
CPU time per simulated ms, and the real-time factor one core could hold
(simulated / CPU time). The reference is the Python protocol model
(sim/icoboard.py); the gateware runs at several FPGA clocks (the board's is
100 MHz; ``[sim] gateware_clk_hz`` picks the one the simulator uses). Also
printed: the compiled design's raw speed in clock cycles per second.
"""

from __future__ import annotations

import argparse
import time

from icefloe.config import Board, Geometry
from icefloe.gateware.cxxsim import CompiledBoard
from icefloe.sim.icoboard import IcoBoardModel
from icefloe.sim.icoboard_gateware import GatewareBoardModel
from icefloe.sim.world import World
from icefloe.wire.icoboard import Op, Wire, duty_to_raw


def per_ms(model, world: World, seconds: float) -> float:
    """CPU seconds per simulated millisecond of world + board + one exchange."""
    wire = Wire(2)
    model.exchange(wire.request(Op.START, seq=1), 0.0)
    duties = [duty_to_raw(0.4), duty_to_raw(-0.4)]
    steps = round(seconds * 1000)
    started = time.process_time()
    for step in range(1, steps + 1):
        now = step / 1000
        world.step(0.001)
        advance = getattr(model, "advance", None)
        if advance is not None:
            advance(now)
        model.tick(now)
        model.exchange(wire.request(Op.TRANSMIT, seq=step + 1, duties=duties), now)
    return (time.process_time() - started) / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per model")
    args = parser.parse_args()
    board = Board(kind="icoboard")

    raw = CompiledBoard(clk_hz=100e6)
    started = time.process_time()
    raw.step(20_000_000)
    speed = 20e6 / (time.process_time() - started)
    raw.close()
    print(f"compiled gateware (CXXRTL, g++ -O2): {speed / 1e6:.2f} M clock cycles per CPU second")

    world = World(Geometry(), seed=1)
    reference = per_ms(IcoBoardModel(world, Wire(2)), world, args.seconds)
    print(f"{'board':<28} {'CPU us per sim ms':>18} {'real-time factor':>17}")
    print(f"{'python model (reference)':<28} {reference * 1e6:>18.0f} {1e-3 / reference:>17.1f}")
    for clk_hz in (0.5e6, 1e6, 2e6, 4e6):
        world = World(Geometry(), seed=1)
        model = GatewareBoardModel(world, board, clk_hz=clk_hz)
        cost = per_ms(model, world, args.seconds)
        model.close()
        print(f"{f'gateware at {clk_hz / 1e6:g} MHz':<28} {cost * 1e6:>18.0f} {1e-3 / cost:>17.1f}")


if __name__ == "__main__":
    main()
