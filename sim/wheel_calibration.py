"""The simulated robot's wheels calibrated as a course calibrates a PenguinPi's (ECE4078's
calibration: drive straight and measure the distance for the scale, spin and measure the angle for the
baseline), for the shipped ``sim`` robot's ``[geometry]``.

The measuring tape is the simulator's truth; the robot is the world at 1 kHz with its profile's true
wheels (`icefloe.sim.realism`), the motors driven by duty without the firmware's controller, as a
course's calibration script drives them by fixed wheel speeds. What it finds is what the robot's
odometry should believe: the mean wheel's rolling diameter (a straight start's slip a little in it) and
the effective track at `TURN_RATE`, where the wheels scrub ``slip_turn`` x the rate of a turn.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass

import msgspec

from icefloe import config as config_mod
from icefloe.config import RobotConfig

from . import realism
from .world import World

STEP_S = 0.001
"""The world's step, s (the simulator's 1 kHz)."""
STRAIGHT_DUTY, STRAIGHT_S = 0.5, 3.0
"""The straight drive: both motors at this duty for this long, s (about 1.2 m)."""
TURN_RATE = 1.5
"""The spin's rate, rad/s: the reference follower's fastest turn (``follower.max_turn_rate``), so the
baseline holds for the turns the reference services make (the effective track grows with the rate)."""
TURN_ANGLE = 2.0
"""How far it spins, rad: within ±π, so the heading needs no unwrapping."""
SHIPPED_SEED = 1
"""The seed the shipped ``sim`` robot's ``[geometry]`` was calibrated with (the random slip)."""


@dataclass(frozen=True)
class WheelCalibration:
    """What the calibration found: what ``[geometry]`` should say."""

    wheel_diameter: float
    """The mean wheel's effective rolling diameter, m (``geometry.wheel_diameter``)."""
    track: float
    """The effective track at `TURN_RATE`, m (``geometry.track``)."""
    turn_rate: float
    """The rate the spin reached, rad/s."""


def _run(world: World, seconds: float) -> None:
    for _ in range(round(seconds / STEP_S)):
        world.step(STEP_S)


def calibrate_wheels(config: RobotConfig, seed: int = SHIPPED_SEED) -> WheelCalibration:
    """Calibrate ``config``'s simulated wheels (its profile's): drive straight, then spin on the spot."""
    g, true = config.geometry, realism.wheels(config)
    world = World(g, seed=seed, slip=true.slip, encoder_noise=true.encoder_noise, wheels=true)
    world.set_duty(STRAIGHT_DUTY, STRAIGHT_DUTY)
    _run(world, STRAIGHT_S)
    world.set_duty(0.0, 0.0)
    _run(world, 0.5)
    left, right = world.counts()
    m_per_count = math.hypot(*world.pose[:2]) / ((left + right) / 2)
    world.set_pose(0.0, 0.0, 0.0)
    start = world.counts()
    duty, reached = 0.15, 0.0  # the spin's duty: raised until the turn runs at TURN_RATE
    for _ in range(40):
        world.set_duty(-duty, duty)
        _run(world, 0.3)
        reached = world.velocity[1]
        if reached >= TURN_RATE:
            break
        duty += 0.01
    while world.pose[2] < TURN_ANGLE:
        world.step(STEP_S)
    world.set_duty(0.0, 0.0)
    _run(world, 0.5)
    left, right = (c - s for c, s in zip(world.counts(), start, strict=True))
    return WheelCalibration(wheel_diameter=m_per_count * g.ticks_per_rev / math.pi,
                            track=(right - left) * m_per_count / world.pose[2], turn_rate=reached)


def main(argv: list[str] | None = None) -> int:
    """``python -m icefloe.sim.wheel_calibration --robot sim``: the ``[geometry]`` a course's calibration
    finds for the realistic robot, to write into deploy/robots/sim.toml (tests/test_shipped_calibration.py
    checks the shipped values are current)."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--robot", default="sim", help="the robot config (a name or a path) whose wheels to calibrate")
    parser.add_argument("--seed", type=int, default=SHIPPED_SEED, help="seed of the wheels' random slip")
    args = parser.parse_args(argv)
    config = config_mod.load(args.robot, credentials=False)
    config = msgspec.structs.replace(config, sim=msgspec.structs.replace(config.sim, profile="realistic"))
    found = calibrate_wheels(config, args.seed)
    print(f"[geometry]\nwheel_diameter = {found.wheel_diameter:.5f}   # m\n"
          f"track = {found.track:.5f}            # m, spinning at {found.turn_rate:.2f} rad/s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
