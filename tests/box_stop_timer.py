"""Times stops sent to the robot in the box from outside, as its owner's laptop sends them
(tests/test_box.py runs it as root, at nice -10: a laptop is not among the box's CPU hogs).

    python tests/box_stop_timer.py BOX_SOCKET ROBOT CREDENTIALS COUNT

Each of COUNT times: drive (held) until the board runs the wheels, drive on for `DRIVE_S`, then
`cmd/stop`. One JSON line per stop, every time on this machine's monotonic clock (the box shares
the kernel, so the board outside it and this client read the same clock), s:

* ``put``: just before the stop is put on the bus (the clock starts when the put leaves the client);
* ``router``: when a second session of this client, subscribed to ``cmd/stop`` through the robot's
  router, got the stop: the put's way to the router and out of it again (the router is the command
  path's one hop that is not real time);
* ``received``: when the datagram that zeroed both wheels' demand reached the board (the board's
  record: `deploy/box/box.py`'s ``received``): the robot's part of a stop;
* ``zero_duty``: since when both duties are zero (the PenguinPi firmware applies a demand at its
  next 20 ms control step: the receipt plus the firmware's wait for it).

The robot drives forwards and backwards in turn, so that it stays where it started.
"""

from __future__ import annotations

import asyncio
import json
import socket
import sys
import time

import zenoh

from icefloe.client import AsyncRobot
from icefloe.schemas import keys

SPEED = 0.2
"""m/s of each drive (the box's other checks drive at it too)."""
DRIVE_S = 0.8
"""How long each drive runs before its stop, s: at 1 kHz (a resting cycle wakes at the command), so
that the cycle's overruns over the stops are the running cycle's."""
WAIT_S = 10.0
"""How long the board may take to start the wheels, or to report a stop, s: far beyond both."""


def board(box_socket: str, request: str) -> str:
    """One request to the box's supervisor (``stopped``, ``received``: see deploy/box/box.py)."""
    with socket.socket(socket.AF_UNIX) as s:
        s.settimeout(WAIT_S)
        s.connect(box_socket)
        s.sendall(request.encode() + b"\n")
        return s.makefile().readline().strip()


def stopped_since(box_socket: str, put: float) -> tuple[float, float] | None:
    """When the last stop reached the board and when the duty became zero, once both are, after ``put``."""
    r = board(box_socket, "received").split()
    if len(r) != 2 or r[1] == "moving" or float(r[0]) < put:
        return None
    return float(r[0]), float(r[1])


async def until(what: str, condition, every: float = 0.005):  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + WAIT_S
    while not (result := condition()):
        if time.monotonic() > deadline:
            raise SystemExit(f"box_stop_timer: {what}: not within {WAIT_S:g} s")
        await asyncio.sleep(every)
    return result


async def main(box_socket: str, robot_name: str, credentials: str, count: int) -> None:
    seen: list[float] = []

    def heard(_sample: zenoh.Sample) -> None:  # the observer's reader thread
        seen.append(time.monotonic())

    async with AsyncRobot(robot_name, credentials=credentials, follow=False) as robot, \
            AsyncRobot(robot_name, credentials=credentials, follow=False, service="stop-observer") as observer:
        observer.node.on_samples(observer.node.key(keys.STOP), heard, allowed_origin=zenoh.Locality.REMOTE)
        for i in range(count):
            await robot.drive(SPEED if i % 2 == 0 else -SPEED, 0.0)  # held until the stop
            await until("the wheels driven", lambda: board(box_socket, "stopped") == "moving")
            await asyncio.sleep(DRIVE_S)
            seen.clear()
            put = time.monotonic()
            await robot.stop(confirm=False)
            received, zero = await until("the board's receipt of the stop and zero duty",
                                         lambda put=put: stopped_since(box_socket, put))
            await until("the observer's copy of the stop", lambda: seen)
            print(json.dumps({"put": put, "router": seen[0], "received": received, "zero_duty": zero}), flush=True)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])))
