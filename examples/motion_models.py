"""The motion-models lab: the same manoeuvre as a unicycle and as a car, each model's prediction
against odometry and the simulator's truth (docs/motion-models.md; needs matplotlib, which
``pip install "icefloe[rtb]"`` brings).

    python examples/motion_models.py                                   # the simulated robot
    python examples/motion_models.py --plot lab.png --robot penguin1 --connect tcp/10.0.0.5:7447

The manoeuvre is a path: straight, then a left arc, then a right arc, at 0.2 m/s. Driven as a
unicycle (``cmd/twist``: turn rate = speed x curvature) the robot changes its turn at once; driven
as a car (``cmd/car``: steering angle = atan(wheelbase x curvature)) its steering turns at the car's
steering rate, so each bend starts late and the path differs. Each model predicts its own path from
the commands alone (as sent: the time each held is measured); the robot's odometry (``odom/pose``)
and, on the simulated robot, its true pose (``sim/truth``) say what happened. Everything is drawn
from where each run started (x ahead, y left). It prints how far each ends from the truth and
writes the plot (a real robot has no truth: then odometry only).
"""

from __future__ import annotations

import argparse
import asyncio
import math
import time

import matplotlib

matplotlib.use("Agg")  # a file, no window: runs on a robot or in a terminal without a display
import matplotlib.pyplot as plt

from icefloe.angles import wrap_angle
from icefloe.client import AsyncRobot, add_robot_arguments, robot_arguments
from icefloe.schemas import keys

SPEED = 0.2
"""Forward speed, m/s."""
MANOEUVRE = [(0.5, 0.0), (1.5, 3.0), (1.5, -3.0)]
"""(seconds, path curvature 1/m, left positive): 0.1 m straight, a 0.33 m-radius arc left, one right."""
DT = 0.005
"""Step of the models' integration, s."""

Pose = tuple[float, float, float]


def unicycle(manoeuvre: list[tuple[float, float]]) -> list[Pose]:
    """The unicycle model: x' = v cos th, y' = v sin th, th' = w, with w = v x curvature at once."""
    x = y = th = 0.0
    path = [(x, y, th)]
    for seconds, curvature in manoeuvre:
        w = SPEED * curvature
        for _ in range(round(seconds / DT)):
            x, y, th = x + SPEED * math.cos(th) * DT, y + SPEED * math.sin(th) * DT, th + w * DT
            path.append((x, y, th))
    return path


def bicycle(manoeuvre: list[tuple[float, float]], wheelbase: float, steer_rate: float) -> list[Pose]:
    """The bicycle model (the car's rear axle): th' = v tan(steer) / L, the steering turning
    towards atan(L x curvature) at ``steer_rate`` rad/s, from where it is."""
    x = y = th = steer = 0.0
    path = [(x, y, th)]
    for seconds, curvature in manoeuvre:
        target = math.atan(wheelbase * curvature)
        for _ in range(round(seconds / DT)):
            steer += max(-steer_rate * DT, min(steer_rate * DT, target - steer))
            x, y = x + SPEED * math.cos(th) * DT, y + SPEED * math.sin(th) * DT
            th += SPEED * math.tan(steer) / wheelbase * DT
            path.append((x, y, th))
    return path


def from_start(poses: list[Pose]) -> list[Pose]:
    """``poses`` in the frame of the first one: x ahead of it, y to its left, heading relative to it."""
    x0, y0, th0 = poses[0]
    c, s = math.cos(th0), math.sin(th0)
    return [(c * (x - x0) + s * (y - y0), -s * (x - x0) + c * (y - y0), wrap_angle(th - th0)) for x, y, th in poses]


async def drive(robot: AsyncRobot, as_car: bool,
                wheelbase: float) -> tuple[list[tuple[float, float]], list[Pose], list[Pose]]:
    """Drive the manoeuvre; return (the manoeuvre as driven: each command's curvature and the time
    it held, s, measured; odometry and truth from just before the first command until the robot
    stood again, each from where it started, truth empty without a simulator)."""
    odom: list[Pose] = []
    truth: list[Pose] = []

    async def listen(topic: keys.Topic, into: list[Pose]) -> None:
        async for msg in robot.node.subscribe(topic, latest=False, maxsize=10_000):
            into.append((msg.x, msg.y, msg.theta))

    tasks = [asyncio.create_task(listen(keys.ODOM_POSE, odom)), asyncio.create_task(listen(keys.TRUTH, truth))]
    await asyncio.sleep(0.3)  # the poses before the first command: where the run starts
    driven, sent = [], time.monotonic()
    for seconds, curvature in MANOEUVRE:
        if as_car:
            await robot.drive_car(SPEED, math.atan(wheelbase * curvature))
        else:
            await robot.drive(SPEED, SPEED * curvature)
        await asyncio.sleep(seconds)
        # a busy computer wakes late: the models get the time each command really held
        driven.append((time.monotonic() - sent, curvature))
        sent += driven[-1][0]
    await robot.stop()
    while abs(robot.pose.v) > 0.002 or abs(robot.pose.w) > 0.01:  # the wheels run down
        await asyncio.sleep(0.05)
    await asyncio.sleep(0.3)
    for task in tasks:
        task.cancel()
    return driven, from_start(odom), from_start(truth) if truth else []


def apart(a: Pose, b: Pose) -> str:
    return f"{math.dist(a[:2], b[:2]) * 1000:5.1f} mm, {math.degrees(abs(wrap_angle(a[2] - b[2]))):4.1f} deg"


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_robot_arguments(parser)
    parser.add_argument("--plot", default="motion-models.png", help="the picture written, PNG")
    args = parser.parse_args()
    async with AsyncRobot(**robot_arguments(args)) as robot:
        await robot.ready("odom/pose", timeout=60)
        info, car = await robot.info(), robot.config.car
        wheelbase = info.wheelbase or car.wheelbase
        runs = {}
        for name, as_car in (("unicycle", False), ("car", True)):
            driven, odom, truth = await drive(robot, as_car, wheelbase)
            predicted = unicycle(driven) if not as_car else bicycle(driven, wheelbase, car.steer_rate)
            runs[name] = (predicted, odom, truth)
            ends = [f"{name:8s} ends: model {apart(predicted[-1], truth[-1] if truth else odom[-1])} from the "
                    f"{'truth' if truth else 'odometry'}"]
            if truth:
                ends.append(f"odometry {apart(odom[-1], truth[-1])} from the truth")
            print("; ".join(ends))

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharex=True, sharey=True)
    for ax, (name, (predicted, odom, truth)) in zip(axes, runs.items(), strict=True):
        ax.plot(*zip(*[p[:2] for p in predicted], strict=True), "--", color="tab:orange", label=f"{name} model")
        ax.plot(*zip(*[p[:2] for p in odom], strict=True), color="tab:blue", label="odometry (odom/pose)")
        if truth:
            ax.plot(*zip(*[p[:2] for p in truth], strict=True), color="0.3", lw=3, alpha=0.4,
                    label="truth (sim/truth)")
        if name == "car":  # the unicycle's prediction beside it: where the steering rate shows
            ax.plot(*zip(*[p[:2] for p in runs["unicycle"][0]], strict=True), ":", color="0.5",
                    label="unicycle model")
        ax.set_title(f"as a {name}: " + ("cmd/twist, w = v x curvature" if name == "unicycle"
                                         else "cmd/car, steer = atan(L x curvature)"), fontsize=10)
        ax.set_xlabel("x, m (ahead of the start)")
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right", fontsize=8)
    axes[0].set_ylabel("y, m (left of the start)")
    fig.suptitle(f"The same path at {SPEED} m/s: straight, a {1 / MANOEUVRE[1][1]:.2f} m arc left, one right "
                 f"(car: L = {wheelbase} m, steering {car.steer_rate} rad/s)", fontsize=11)
    fig.tight_layout()
    fig.savefig(args.plot, dpi=90)
    print(f"wrote {args.plot}")


if __name__ == "__main__":
    asyncio.run(main())
