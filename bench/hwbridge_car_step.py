"""What the virtual car costs hwbridge's bus process: one `Bridge.car_step` (the 50 Hz step of
``cmd/car``'s steering and the ``car/state`` it returns), standing and while the steering turns,
and one `Bridge.car` (a ``cmd/car`` taken), next to one `Bridge.twist` (a ``cmd/twist`` taken,
the reference, measured in the same run).

    .venv/bin/python bench/hwbridge_car_step.py [--repeat 20000]

The Bridge writes to a real shared-memory block, as in hwbridge; no cycle reads it, no bus.
The publication of ``car/state`` itself is a `Node` put (docs/runtime.md measures those).
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import time

from icefloe.config import RobotConfig
from icefloe.ordering import Origin
from icefloe.schemas import messages as m
from icefloe.services.hwbridge.bridge import Bridge
from icefloe.services.hwbridge.shm import Shared


def per_call_us(run, repeat: int) -> float:
    best = float("inf")
    for _ in range(5):  # the best of five: other processes on a shared machine only ever add
        start = time.perf_counter()
        for i in range(repeat):
            run(i)
        best = min(best, (time.perf_counter() - start) / repeat * 1e6)
    return best


async def main(repeat: int) -> None:
    shared = Shared.create()
    log = logging.getLogger("bench")
    log.addHandler(logging.NullHandler())
    log.propagate = False
    try:
        bridge = Bridge(RobotConfig(), shared, log)
        t0 = time.monotonic_ns()
        twist = per_call_us(lambda i: bridge.twist(m.Twist(v=0.1, w=0.2), Origin(t0 + i)), repeat)
        car = per_call_us(lambda i: bridge.car(m.CarDrive(v=0.1, steer=0.3), Origin(t0 + i)), repeat)
        bridge.stop()
        standing = per_call_us(lambda i: bridge.car_step(t0 + i * 20_000_000), repeat)
        rate = RobotConfig().car.state_rate_hz

        def turning(i: int) -> None:  # steering from side to side, a step of the ramp each call
            if i % 20 == 0:
                bridge.car(m.CarDrive(v=0.1, steer=0.6 if i % 40 else -0.6), Origin(time.monotonic_ns()))
            bridge.car_step(time.monotonic_ns())

        steering = per_call_us(turning, repeat)
    finally:
        shared.close()
    print(f"reference: Bridge.twist (a cmd/twist taken)       {twist:6.2f} µs")
    print(f"Bridge.car (a cmd/car taken)                       {car:6.2f} µs  ({car / twist:.2f}x)")
    print(f"Bridge.car_step, standing                          {standing:6.2f} µs  "
          f"({standing / twist:.2f}x; at {rate:g} Hz: {standing * rate / 1e4:.3f} % of a core)")
    print(f"Bridge.car_step, steering (1 in 20 with a cmd/car) {steering:6.2f} µs  "
          f"({steering / twist:.2f}x; at {rate:g} Hz: {steering * rate / 1e4:.3f} % of a core)")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20000, help="calls per measurement (best of five)")
    asyncio.run(main(parser.parse_args().repeat))
