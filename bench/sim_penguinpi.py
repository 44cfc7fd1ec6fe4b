"""How fast is the simulated PenguinPi, and how close to the real serial link?

    .venv/bin/python bench/sim_penguinpi.py [--exchanges 300]

Prints, each next to a reference measured in the same run:

1. Cost of one simulated millisecond (world.step + firmware tick), against
   world.step alone; the 1 kHz clock needs well under 1000 µs.
2. Round trip of MULTI_SET_VEL_GET_ENC (7 bytes out, 9 back) through pyserial
   and the pseudo-terminal, against the line time at 115200 baud (16 bytes x
   10 bits = 1.39 ms, the floor on real hardware) and against a bare pty echo
   (what the pseudo-terminal plus threads cost without any model).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import threading
import time
import tty
from pathlib import Path

import serial

from icefloe.config import Board, Geometry
from icefloe.sim.clock import SimClock
from icefloe.sim.penguinpi import PenguinPiSim
from icefloe.sim.penguinpi_firmware import PenguinPiFirmware
from icefloe.sim.world import World
from icefloe.wire import penguinpi as w

REQUEST = w.encode_frame(w.Address.AD_MULTI, w.MultiOp.MULTI_SET_VEL_GET_ENC, w.pack_multi_set(20, 20))
REPLY_LEN = 9


def per_step_us(steps: int = 20000) -> tuple[float, float]:
    """(world.step alone, world.step + firmware tick), µs per simulated millisecond."""
    world = World(Geometry(), seed=1)
    world.set_duty(0.4, 0.4)
    start = time.perf_counter()
    for _ in range(steps):
        world.step(0.001)
    bare = (time.perf_counter() - start) / steps * 1e6
    world = World(Geometry(), seed=1)
    clock = SimClock(world, [PenguinPiFirmware(world)])
    start = time.perf_counter()
    for _ in range(steps):
        clock.step()
    full = (time.perf_counter() - start) / steps * 1e6
    return bare, full


def read_exactly(port: serial.Serial, size: int) -> bytes:
    data = port.read(size)
    if len(data) != size:
        raise RuntimeError(f"short read: {len(data)} of {size} bytes")
    return data


def round_trips(port: serial.Serial, count: int) -> list[float]:
    """Seconds per request/reply, after the port has been drained."""
    times = []
    for _ in range(count):
        start = time.perf_counter()
        port.write(REQUEST)
        read_exactly(port, REPLY_LEN)
        times.append(time.perf_counter() - start)
    return times


def sim_round_trips(count: int) -> list[float]:
    with tempfile.TemporaryDirectory() as tmp:
        world = World(Geometry(), seed=1)
        board = Board(serial_port=str(Path(tmp) / "ttyPPI"))
        sim = PenguinPiSim(world, board)
        with SimClock(world, [sim]):
            port = serial.Serial(board.serial_port, board.baud, timeout=1.0, exclusive=True)
            time.sleep(0.05)
            port.reset_input_buffer()          # the boot line
            times = round_trips(port, count)
            port.close()
        sim.close()
    return times


def echo_round_trips(count: int) -> list[float]:
    """The same exchange against a thread that answers 9 bytes at once: the pty's own cost."""
    master, slave = os.openpty()
    tty.setraw(slave)
    stop = threading.Event()

    def echo() -> None:
        while not stop.is_set():
            got = b""
            while len(got) < len(REQUEST) and not stop.is_set():
                got += os.read(master, 64)
            os.write(master, bytes(REPLY_LEN))

    thread = threading.Thread(target=echo, daemon=True)
    thread.start()
    port = serial.Serial(os.ttyname(slave), 115200, timeout=1.0)
    times = round_trips(port, count)
    stop.set()
    port.write(REQUEST)                        # release the echo thread
    thread.join(1.0)
    port.close()
    os.close(master)
    os.close(slave)
    return times


def summary(times: list[float]) -> str:
    ms = sorted(t * 1e3 for t in times)
    p99 = ms[min(len(ms) - 1, int(len(ms) * 0.99))]
    return (f"mean {statistics.fmean(ms):6.3f} ms  median {statistics.median(ms):6.3f}"
            f"  p99 {p99:6.3f}  max {ms[-1]:6.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--exchanges", type=int, default=300)
    args = parser.parse_args()
    bare, full = per_step_us()
    print("one simulated millisecond:")
    print(f"  world.step alone            {bare:7.1f} µs")
    print(f"  world.step + firmware tick  {full:7.1f} µs   (budget at 1 kHz: 1000 µs)")
    line = (len(REQUEST) + REPLY_LEN) * 10 / 115200 * 1e3
    print(f"MULTI_SET_VEL_GET_ENC round trip, {args.exchanges} exchanges:")
    print(f"  line time at 115200 baud    {line:6.3f} ms   (floor on the real robot)")
    print(f"  bare pty echo (reference)   {summary(echo_round_trips(args.exchanges))}")
    print(f"  simulated PenguinPi         {summary(sim_round_trips(args.exchanges))}")


if __name__ == "__main__":
    main()
