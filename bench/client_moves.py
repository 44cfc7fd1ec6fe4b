"""How close `Robot.forward` and `Robot.turn` get, on the simulated robot's ground truth.

    .venv/bin/python bench/client_moves.py [--rounds 3]

Starts the simulated robot (``icefloe up`` with sim, hwbridge, odometry, info) and runs a plan
of moves through `icefloe.client.AsyncRobot` (forward 0.3, 0.05, 0.5 m and back 0.2 m; turns of
90, -180, 10 and -45 degrees), ``--rounds`` times. Each move's error is the simulator's true
motion (``sim/control``) minus what was asked, measured once the robot has settled.

Reference, same run: the same moves open loop, as a student would write them without
`forward`: one timed motion each (``set_velocity(v, v, duration=distance / v)``, at the same
speeds), whose errors are the wheels' start-up and coasting.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import robot_config

from icefloe.client import AsyncRobot
from icefloe.config import load
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m

FORWARD_SPEED, TURN_SPEED = 0.15, 1.0
"""The defaults of `forward` (m/s) and `turn` (rad/s)."""
PLAN = [("forward", 0.3), ("turn", math.pi / 2), ("forward", -0.2), ("turn", -math.pi),
        ("forward", 0.05), ("turn", math.radians(10)), ("forward", 0.5), ("turn", math.radians(-45))]


async def truth(node: Node) -> m.SimState:
    return await node.query(keys.SIM_CONTROL, m.SimControl(action="read"), timeout=5)


async def move(robot: AsyncRobot, kind: str, amount: float, closed: bool) -> None:
    if closed:
        await (robot.forward(amount) if kind == "forward" else robot.turn(amount))
        return
    track = (await robot.info()).track
    rim = FORWARD_SPEED if kind == "forward" else TURN_SPEED * track / 2
    travel = abs(amount) if kind == "forward" else abs(amount) * track / 2
    sign = math.copysign(1.0, amount)
    left, right = (sign * rim, sign * rim) if kind == "forward" else (-sign * rim, sign * rim)
    await robot.set_velocity(left, right, duration=travel / rim)


async def run(config: Path, rounds: int) -> dict[tuple[bool, str], list[float]]:
    errors: dict[tuple[bool, str], list[float]] = {(c, k): [] for c in (True, False) for k in ("forward", "turn")}
    cfg = load(config)
    async with Node("bench", cfg) as node, AsyncRobot(config=cfg, timeout=10) as robot:
        await robot.ready(keys.ODOM_POSE.name)
        for _ in range(rounds):
            for closed in (True, False):
                for kind, amount in PLAN:
                    before = await truth(node)
                    await move(robot, kind, amount, closed)
                    await asyncio.sleep(0.5)  # settled
                    after = await truth(node)
                    if kind == "forward":
                        done = ((after.x - before.x) * math.cos(before.theta)
                                + (after.y - before.y) * math.sin(before.theta))
                        errors[closed, kind].append(1000 * (done - amount))
                    else:
                        done = math.remainder(after.theta - before.theta, math.tau)
                        errors[closed, kind].append(math.degrees(math.remainder(done - amount, math.tau)))
    return errors


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=3)
    args = p.parse_args()
    config = robot_config(Path(tempfile.mkdtemp()), "movebench")
    up = subprocess.Popen([sys.executable, "-m", "icefloe.cli", "up", str(config), "--no-viz",
                           "--only", "sim,hwbridge,odometry,info"],
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        time.sleep(5.0)  # every service up
        errors = asyncio.run(run(config, args.rounds))
    finally:
        up.send_signal(signal.SIGINT)
        up.wait(60)
    n = len(PLAN) // 2 * args.rounds
    print(f"{n} forward moves (0.05-0.5 m) and {n} turns (10-180°) each, errors against the simulator's truth:")
    for closed in (True, False):
        name = "forward()/turn(), closed loop on odometry" if closed else "timed set_velocity (reference)"
        f, t = errors[closed, "forward"], errors[closed, "turn"]
        print(f"  {name:<44} forward |err| mean {statistics.fmean(map(abs, f)):5.1f} mm  max "
              f"{max(map(abs, f)):5.1f} mm   turn |err| mean {statistics.fmean(map(abs, t)):4.1f}°  max "
              f"{max(map(abs, t)):4.1f}°")


if __name__ == "__main__":
    main()
