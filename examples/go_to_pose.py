"""Drive to a goal pose using only the lab's overhead camera (the course's motion-control task).

    python examples/go_to_pose.py --robot penguin7 --credentials penguin7.credentials --x 1.0 --y 0.5 --theta 1.57

The robot's pose comes from `robot.external_pose` alone: the lab's localizer sees the robot's
top marker from the ceiling and publishes its pose in the world frame (docs/extloc.md). No
odometry, no localizer of our own: this is the controller a student writes before localization
is taught.

The camera's pose arrives late (a frame's time, detection, the network: from a few
milliseconds on a lab machine to a second on a busy one), so the robot does not steer by it
while it moves. It looks, moves, stops and looks again, as one would with the old localiser's
two poses a second:

1. look (a pose taken once the robot has come to rest);
2. if it is far from the goal point: turn on the spot to face it, look again, drive the
   distance to it; else turn on the spot to the goal heading;
3. again, until within tolerance.

Each move is a timed motion (`robot.drive(v, w, duration)`), timed on the robot itself. The
wheels lag it: static friction holds a wheel until its motor's duty is past a dead band, and the
board's controller takes a while to wind the duty up that far (about 5° of a turn, whatever the
rate), and after the stop the wheels coast on for a moment. A long move comes out about right (it
starts late and coasts on); a short one falls short or does not happen at all. So the robot waits
for its wheels to come to rest before it looks, and a small turn is made of two long ones (`turn`).
"""

from __future__ import annotations

import argparse
import math
import time

from icefloe.angles import wrap_angle
from icefloe.client import Robot, add_robot_arguments, robot_arguments
from icefloe.schemas.messages import ExternalPose

SPEED = 0.12
"""Forward speed, m/s."""
TURN_RATE = 1.0
"""Turn rate on the spot, rad/s."""
POSITION_TOLERANCE = 0.03
"""Close enough to the goal point, m."""
HEADING_TOLERANCE = math.radians(3)
"""Close enough to a heading, rad."""
MIN_TURN = math.radians(20)
"""The smallest turn the wheels execute as asked, rad. Measured on the simulated PenguinPi at 1 rad/s:
20° turned 18-21°, 25° and more within a degree; 12° turned 7-9°, 8° 1-2°, 5° not at all. Slower is
no better: at 0.3 rad/s, 10° turned 6-8° (the wheels stick and slip)."""
SETTLE_S = 0.5
"""Time for the wheels to come to rest after a move (they coast on after the stop), s."""
MOVES = 12
"""Give up after this many moves."""
BLIND_S = 10.0
"""No new external pose for this long: stop trying, s."""


def look(robot: Robot) -> ExternalPose:
    """The robot's pose, standing still: wait `SETTLE_S` for the wheels to come to rest, then the
    second new external pose (the first may be of a frame taken while it was still moving). Exits
    if none comes for `BLIND_S`."""
    time.sleep(SETTLE_S)
    pose = robot.external_pose  # waits for the first one
    for _ in range(2):
        stamp, deadline = pose.stamp, time.monotonic() + BLIND_S
        while (pose := robot.external_pose).stamp == stamp:
            if time.monotonic() > deadline:
                raise SystemExit(f"no external pose for {BLIND_S:.0f} s: is the robot in the camera's view?")
            time.sleep(0.02)
    return pose


def turn(robot: Robot, angle: float) -> None:
    """Turn on the spot by ``angle`` rad (CCW positive), timed on the robot.

    A turn smaller than `MIN_TURN` would fall short or not happen at all (static friction), so it
    is made of two that do happen: `MIN_TURN` past the heading we want, and, once the wheels have
    come to rest, `MIN_TURN` back."""
    if abs(angle) >= MIN_TURN:
        robot.drive(0.0, math.copysign(TURN_RATE, angle), duration=abs(angle) / TURN_RATE)
        return
    past = math.copysign(MIN_TURN, angle)
    turn(robot, angle + past)
    time.sleep(SETTLE_S)
    turn(robot, -past)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_robot_arguments(parser)
    parser.add_argument("--x", type=float, required=True, help="goal x, world frame, m")
    parser.add_argument("--y", type=float, required=True, help="goal y, world frame, m")
    parser.add_argument("--theta", type=float, default=0.0, help="goal heading, rad, CCW from +x")
    args = parser.parse_args()

    with Robot(**robot_arguments(args)) as robot:
        here = look(robot)
        print(f"start: x {here.x:.3f} m, y {here.y:.3f} m, theta {math.degrees(here.theta):.1f}°")
        for move in range(1, MOVES + 1):
            distance = math.hypot(args.x - here.x, args.y - here.y)
            if distance > POSITION_TOLERANCE:
                facing = wrap_angle(math.atan2(args.y - here.y, args.x - here.x) - here.theta)
                if abs(facing) > HEADING_TOLERANCE:
                    turn(robot, facing)
                    here = look(robot)
                    facing = wrap_angle(math.atan2(args.y - here.y, args.x - here.x) - here.theta)
                # Drive what lies ahead along our heading (less, if we are not quite facing it).
                ahead = distance * math.cos(facing)
                if ahead > 0.005:
                    robot.drive(SPEED, 0.0, duration=ahead / SPEED)
                what = "drove"
            else:
                error = wrap_angle(args.theta - here.theta)
                if abs(error) <= HEADING_TOLERANCE:
                    break
                turn(robot, error)
                what = "turned"
            here = look(robot)
            print(f"move {move} ({what}): x {here.x:.3f} m, y {here.y:.3f} m, theta {math.degrees(here.theta):.1f}°")
        distance = math.hypot(here.x - args.x, here.y - args.y)
        error = abs(wrap_angle(args.theta - here.theta))
        done = distance <= POSITION_TOLERANCE and error <= HEADING_TOLERANCE
        print(f"{'goal reached' if done else 'gave up'}: x {here.x:.3f} m, y {here.y:.3f} m, "
              f"theta {math.degrees(here.theta):.1f}° ({distance * 1000:.0f} mm, "
              f"{math.degrees(error):.1f}° from the goal)")
        if not done:
            raise SystemExit(1)


if __name__ == "__main__":
    main()
