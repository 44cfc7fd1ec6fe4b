"""What a period with nothing to do costs: odometry's loop when no ``hw/wheels`` sample comes.

    .venv/bin/python bench/empty_wakeups.py [--seconds 10]

`Node.batches` wakes once per period and looks into Zenoh's ring channel; with no sample there
is nothing else to do. This runs the same loop (an asyncio sleep to an absolute deadline, then
``try_recv`` until empty) on a Zenoh session of its own, on a key nobody publishes, at odometry's
50 Hz, at its 4 Hz heartbeat, and at 0.1 Hz (the reference: the session alone), and prints the CPU
time per wall second of each (docs/deploy.md, "At rest").
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import time

import zenoh


async def loop_cpu(rate_hz: float, seconds: float) -> float:
    """% of one core this process used over ``seconds`` waking at ``rate_hz`` into an empty channel."""
    config = zenoh.Config()
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", json.dumps([]))
    session = zenoh.open(config)
    sub = session.declare_subscriber("icefloe/nobody/hw/wheels", zenoh.handlers.RingChannel(4096))
    await asyncio.sleep(1.0)  # the session's start-up is behind us
    loop = asyncio.get_running_loop()
    cpu0, wall0 = time.process_time(), time.monotonic()
    deadline = loop.time()
    while time.monotonic() - wall0 < seconds:
        deadline += 1.0 / rate_hz
        await asyncio.sleep(deadline - loop.time())
        while sub.try_recv() is not None:
            pass
    used = 100 * (time.process_time() - cpu0) / (time.monotonic() - wall0)
    session.close()
    return used


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=10.0, help="length of each window, s")
    args = p.parse_args()
    print(f"an empty period's cost, {args.seconds:g} s each; load average {os.getloadavg()[0]:.1f}")
    for rate in (50.0, 4.0, 0.1):
        print(f"  {rate:5g} Hz: {asyncio.run(loop_cpu(rate, args.seconds)):.3f} % of one core")
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
