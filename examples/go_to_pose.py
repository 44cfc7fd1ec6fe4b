"""Drive to a goal pose using only the lab's overhead camera (the course's motion-control task).

    python examples/go_to_pose.py --robot penguin7 --credentials penguin7.credentials --x 1.0 --y 0.5 --theta 1.57

The robot's pose comes from `robot.external_pose` alone: the lab's localizer sees the robot's
top marker from the ceiling and publishes its pose in the world frame (docs/extloc.md). No
odometry, no localizer of our own: this is the controller a student writes before localization
is taught. Three moves, each a proportional controller on the latest external pose:

1. turn on the spot to face the goal point;
2. drive to it, steering towards it all the way;
3. turn on the spot to the goal heading.

The camera's pose arrives a little late (a frame's time, plus detection, plus the network), and
the wheels stop a little late: after each move the robot stands still, looks again with a pose
taken after it stopped, and does the moves again from there until it is within tolerance.

If no new external pose comes for `STALE_S` (the robot left the camera's view, or the localizer
stopped), the robot stops and waits: driving blind is not allowed.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable

from icefloe.client import Robot, add_robot_arguments, robot_arguments
from icefloe.schemas.messages import ExternalPose

Step = Callable[[ExternalPose], tuple[float, float] | None]
"""One control step: from the pose, the (v m/s, w rad/s) to drive at, or None when done."""

PERIOD = 0.05
"""Control period, s."""
STALE_S = 0.5
"""A pose that has not changed for this long is no pose: stop, s."""
MAX_V, MAX_W = 0.12, 1.0
"""Largest forward speed (m/s) and turn rate (rad/s) we ask for."""
K_V, K_W = 0.8, 2.0
"""Gains: m/s per m of distance, rad/s per rad of heading error."""
POSITION_TOLERANCE = 0.02
"""Close enough to the goal point, m."""
HEADING_TOLERANCE = math.radians(3)
"""Close enough to a heading, rad."""


def angle_to(target: float, theta: float) -> float:
    """Signed angle from ``theta`` to ``target``, wrapped to (-pi, pi], rad."""
    return math.atan2(math.sin(target - theta), math.cos(target - theta))


class Seen:
    """The latest external pose, and whether it is fresh (its stamp changed in the last `STALE_S`
    of our own clock: the lab machine's clock and ours need not agree)."""

    def __init__(self, robot: Robot) -> None:
        self.robot, self.stamp, self.changed = robot, 0, 0.0

    def pose(self) -> ExternalPose | None:
        """The latest external pose, or None while the robot is not seen."""
        pose = self.robot.external_pose
        now = time.monotonic()
        if pose.stamp != self.stamp:
            self.stamp, self.changed = pose.stamp, now
        return pose if now - self.changed < STALE_S else None


def control(robot: Robot, seen: Seen, step: Step) -> None:
    """Run ``step(pose) -> (v, w) or None`` every `PERIOD` until it says done (None)."""
    while True:
        pose = seen.pose()
        if pose is None:
            robot.stop()
            print("no external pose: stopped, waiting to be seen again")
            while (pose := seen.pose()) is None:
                time.sleep(PERIOD)
        command = step(pose)
        if command is None:
            robot.stop()
            return
        robot.drive(*command)
        time.sleep(PERIOD)


def clamp(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))


def turn_to(robot: Robot, seen: Seen, heading: Callable[[ExternalPose], float]) -> None:
    """Turn on the spot until facing ``heading(pose)`` (rad)."""
    def step(pose: ExternalPose) -> tuple[float, float] | None:
        error = angle_to(heading(pose), pose.theta)
        if abs(error) < HEADING_TOLERANCE:
            return None
        return 0.0, clamp(K_W * error, MAX_W) if abs(error) > 0.2 else math.copysign(0.3, error)
    control(robot, seen, step)


def drive_to(robot: Robot, seen: Seen, x: float, y: float) -> None:
    """Drive to (x, y), steering towards it, until within `POSITION_TOLERANCE` or past it."""
    def step(pose: ExternalPose) -> tuple[float, float] | None:
        dx, dy = x - pose.x, y - pose.y
        ahead = dx * math.cos(pose.theta) + dy * math.sin(pose.theta)  # m still to go along our heading
        if math.hypot(dx, dy) < POSITION_TOLERANCE or ahead <= 0:
            return None
        bearing = angle_to(math.atan2(dy, dx), pose.theta)
        v = clamp(K_V * ahead, MAX_V) * max(0.0, math.cos(bearing))
        return max(v, 0.03), clamp(K_W * bearing, MAX_W) if ahead > 0.05 else 0.0
    control(robot, seen, step)


def settled(robot: Robot, seen: Seen) -> ExternalPose:
    """A pose of the robot standing still: taken after the stop (two new frames later)."""
    robot.stop()
    for _ in range(2):
        stamp = seen.stamp
        while (pose := seen.pose()) is None or pose.stamp == stamp:
            time.sleep(PERIOD)
    return pose


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_robot_arguments(parser)
    parser.add_argument("--x", type=float, required=True, help="goal x, world frame, m")
    parser.add_argument("--y", type=float, required=True, help="goal y, world frame, m")
    parser.add_argument("--theta", type=float, default=0.0, help="goal heading, rad, CCW from +x")
    args = parser.parse_args()

    with Robot(**robot_arguments(args)) as robot:
        seen = Seen(robot)
        start = robot.external_pose  # waits for the first one
        print(f"start: x {start.x:.3f} m, y {start.y:.3f} m, theta {math.degrees(start.theta):.1f}°")
        for attempt in range(1, 6):
            here = settled(robot, seen)
            if math.hypot(args.x - here.x, args.y - here.y) > POSITION_TOLERANCE * 1.5:
                turn_to(robot, seen, lambda p: math.atan2(args.y - p.y, args.x - p.x))
                drive_to(robot, seen, args.x, args.y)
            elif abs(angle_to(args.theta, here.theta)) > HEADING_TOLERANCE * 1.5:
                turn_to(robot, seen, lambda p: args.theta)
            else:
                break
            print(f"move {attempt} done")
        end = settled(robot, seen)
        print(f"goal reached: x {end.x:.3f} m, y {end.y:.3f} m, theta {math.degrees(end.theta):.1f}° "
              f"({math.hypot(end.x - args.x, end.y - args.y) * 1000:.0f} mm, "
              f"{math.degrees(abs(angle_to(args.theta, end.theta))):.1f}° from the goal)")


if __name__ == "__main__":
    main()
