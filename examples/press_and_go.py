"""Wait for the user button, then drive out and back: buttons, LEDs, the DIP switch, forward and turn.

    python examples/press_and_go.py                  # the simulated robot; press S4 with:
    icefloe query sim/control '{"action": "press_button", "button": 3}'
    python examples/press_and_go.py --robot penguin1 --connect tcp/10.0.0.5:7447 --credentials penguin1.credentials

LED 2 blinks while the robot waits for a press of S4 (the user button on the PenguinPi's HAT).
Then it drives ``--distance`` ahead, turns round, comes back and turns round again, each move
closed on odometry (`Robot.forward`, `Robot.turn`). Ctrl-C at any time stops the wheels.
"""

from __future__ import annotations

import argparse
import math

from icefloe.client import Robot, add_robot_arguments, robot_arguments


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_robot_arguments(parser)
    parser.add_argument("--distance", type=float, default=0.3, help="how far out, m")
    args = parser.parse_args()

    with Robot(**robot_arguments(args)) as robot:
        print(f"DIP switches: {robot.dip:04b}")
        # Called on the robot's callback thread at every press, also while we drive.
        robot.buttons["S4"].when_pressed = lambda button: print(f"{button.name} pressed "
                                                                f"({button.presses} so far)", flush=True)
        robot.led(2, blink=0.25)
        print("press S4 to start", flush=True)
        robot.wait_for_press("S4")
        robot.led(2, True)
        start = robot.pose
        for _ in range(2):
            robot.forward(args.distance)
            robot.turn(math.pi)
        robot.led(2, False)
        end = robot.pose
        print(f"back: {math.hypot(end.x - start.x, end.y - start.y) * 1000:.0f} mm from the start "
              f"by odometry, heading {math.degrees(math.remainder(end.theta - start.theta, math.tau)):+.1f}°")


if __name__ == "__main__":
    main()
