"""Drive a square, steering by odometry, with the blocking `Robot` client.

    python examples/drive_square.py                                   # the simulated robot
    python examples/drive_square.py --robot penguin1 --connect tcp/10.0.0.5:7447

Each side is "go to the next corner": turn on the spot to face it, drive
towards it until odometry says we are there, stop. The corners are fixed points in the odometry
frame, so the small overshoots of one side are corrected by the next instead of
adding up (as "drive 0.3 m, turn 90°" four times would let them).
"""

from __future__ import annotations

import argparse
import math
import time

from icefloe.angles import wrap_angle
from icefloe.client import Robot, add_robot_arguments, robot_arguments

SPEED = 0.20
"""Forward speed of both wheels, m/s."""
STEER = 0.3
"""Wheel speed difference per radian of bearing to the target, (m/s)/rad."""
MAX_STEER = 0.15
"""Largest steering difference, m/s: SPEED + MAX_STEER stays within the robot's max_wheel_speed
(0.5 m/s; set_velocity raises ValueError beyond it) however far off the bearing is."""
TURN = 0.10
"""Wheel speed when turning on the spot, m/s (1.3 rad/s with a 156 mm track)."""
CREEP = 0.04
"""Wheel speed for the last bit of each move, m/s: the robot stops a little late
(the command crosses the network, the wheels decelerate), so arrive slowly."""
CREEP_DISTANCE = 0.04
"""Drive the last this many metres of a side at CREEP."""
CREEP_ANGLE = math.radians(15)
"""Turn the last this many radians at CREEP."""
TOLERANCE = math.radians(1.5)
"""Heading error we accept after a turn, rad."""


def wait_until_still(robot: Robot) -> None:
    """Wait until odometry says the wheels have stopped (the stop takes a moment)."""
    while abs(robot.pose.v) > 0.002 or abs(robot.pose.w) > 0.01:
        time.sleep(0.02)


def drive_to(robot: Robot, x: float, y: float) -> None:
    """Drive to the point (x, y) of the odometry frame (m), steering towards it, then stop.

    Steering matters: after a turn the wheels' speed controllers are still
    wound up in opposite directions, and the robot would curve away.
    """
    while True:
        here = robot.pose
        dx, dy = x - here.x, y - here.y
        ahead = dx * math.cos(here.theta) + dy * math.sin(here.theta)  # m still to go
        if ahead <= 0:
            break
        if ahead > CREEP_DISTANCE:
            steer = STEER * wrap_angle(math.atan2(dy, dx) - here.theta)
            steer = max(-MAX_STEER, min(MAX_STEER, steer))
            robot.set_velocity(SPEED - steer, SPEED + steer)
        else:  # nearly there: the bearing of a close point swings wildly, go straight
            robot.set_velocity(CREEP, CREEP)
        time.sleep(0.05)
    robot.stop()
    wait_until_still(robot)


def turn_to(robot: Robot, heading: float) -> None:
    """Turn on the spot to ``heading`` (rad, counter-clockwise positive), then stop.

    The wheels stop late (the firmware's speed loop is slow to wind down), so
    after stopping we look again and correct while the error is over TOLERANCE.
    """
    for _ in range(3):
        error = wrap_angle(heading - robot.pose.theta)
        if abs(error) < TOLERANCE:
            return
        direction = math.copysign(1.0, error)  # +1: counter-clockwise
        speed = 0.0
        while (left := direction * wrap_angle(heading - robot.pose.theta)) > 0:
            wanted = TURN if left > CREEP_ANGLE else CREEP
            if wanted != speed:
                speed = wanted
                robot.set_velocity(-direction * speed, direction * speed)
            time.sleep(0.01)
        robot.stop()
        wait_until_still(robot)


def go_to(robot: Robot, x: float, y: float) -> None:
    """Turn to face the point (x, y) of the odometry frame (m), then drive to it."""
    here = robot.pose
    turn_to(robot, math.atan2(y - here.y, x - here.x))
    drive_to(robot, x, y)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_robot_arguments(parser)
    parser.add_argument("--side", type=float, default=0.3, help="side of the square, m")
    args = parser.parse_args()

    with Robot(**robot_arguments(args)) as robot:
        start = robot.pose
        print("start:", robot)
        c, s = math.cos(start.theta), math.sin(start.theta)
        # The square's corners, counter-clockwise, ahead and to the left of the start.
        for n, (ahead, left) in enumerate([(1, 0), (1, 1), (0, 1), (0, 0)], 1):
            ahead, left = ahead * args.side, left * args.side
            go_to(robot, start.x + ahead * c - left * s, start.y + ahead * s + left * c)
            print(f"corner {n}:", robot)
        turn_to(robot, start.theta)
        print("end:", robot)


if __name__ == "__main__":
    main()
