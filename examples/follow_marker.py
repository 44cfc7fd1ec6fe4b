"""Find an ArUco marker with the camera and drive up to it.

    python examples/follow_marker.py --marker 1                  # the simulated robot
    python examples/follow_marker.py --marker 4 --robot penguin1 --connect tcp/10.0.0.5:7447

The camera service reports each marker it sees as a range (m) and a bearing
(rad, counter-clockwise positive: positive = to the left). Until the marker is
in view, turn on the spot to look for it; then drive towards it, steering to
keep its bearing at zero, and stop ``--stop`` metres in front of it.
"""

from __future__ import annotations

import argparse
import time

from icefloe.client import Robot, add_robot_arguments, robot_arguments
from icefloe.schemas.messages import Landmark

SPEED = 0.15
"""Forward speed while approaching, m/s."""
SEARCH = 0.05
"""Wheel speed while turning to look for the marker, m/s."""
STEER = 0.2
"""Wheel speed difference per radian of bearing, (m/s)/rad."""
PERIOD = 0.1
"""How often we look and steer, s."""


def find(robot: Robot, marker: int) -> Landmark | None:
    """The marker in the latest camera frame, or None if it is not in view."""
    return next((seen for seen in robot.landmarks if seen.id == marker), None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_robot_arguments(parser)
    parser.add_argument("--marker", type=int, default=1, help="ArUco id of the marker to reach")
    parser.add_argument("--stop", type=float, default=0.4, help="stop this far from the marker, m")
    parser.add_argument("--give-up", type=float, default=60.0, help="give up after this long, s")
    args = parser.parse_args()

    with Robot(**robot_arguments(args), timeout=10.0) as robot:
        deadline = time.monotonic() + args.give_up
        while time.monotonic() < deadline:
            seen = find(robot, args.marker)
            if seen is None:
                robot.set_velocity(-SEARCH, SEARCH)  # turn left on the spot, looking
            elif seen.range <= args.stop:
                robot.stop()
                print(f"reached marker {args.marker}: {seen.range:.2f} m ahead, "
                      f"bearing {seen.bearing:+.2f} rad")
                return
            else:
                steer = STEER * seen.bearing  # marker to the left: right wheel faster
                robot.set_velocity(SPEED - steer, SPEED + steer)
            time.sleep(PERIOD)
        robot.stop()
        raise SystemExit(f"marker {args.marker} not reached within {args.give_up} s")


if __name__ == "__main__":
    main()
