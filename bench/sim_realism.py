"""What the simulator's profiles do to odometry: the same open-loop tour, the same seed, in the ideal
and the realistic profile (`icefloe.sim.realism`, docs/sim.md), odometry from the encoder counts as the
robot's software believes its wheels ([geometry]) against the simulator's truth: the drawing's wheels
(`Geometry`'s defaults) in both profiles, and last the shipped ``sim`` robot as it ships: realistic, its
[geometry] a course's calibration of the realistic wheels (`icefloe.sim.wheel_calibration`).

    .venv/bin/python bench/sim_realism.py [--seed N] [--laps N]

The world alone (`sim/world.py`) at 1 kHz, no board, no processes: the PenguinPi firmware's speed
controller is not in the loop, so the duties are the tour's own (a few seconds of CPU). The reference
line is the ideal profile: its odometry is exact but for the counts' quantisation.
"""

from __future__ import annotations

import argparse
import math

from icefloe import config as config_mod
from icefloe.angles import wrap_angle
from icefloe.estimation.odometry import make_odometry
from icefloe.sim import realism
from icefloe.sim.world import World

SIDE = ((0.5, 0.5, 2.0), (0.0, 0.0, 0.5), (-0.4, 0.4, 0.62), (0.0, 0.0, 0.5))
"""One side of the tour: (left duty, right duty, s): about 0.8 m straight, stop, a quarter turn left, stop."""
SAMPLE_S = 0.005
"""Odometry takes the counts every 5 ms, as hwbridge's 200 Hz serial rate."""


def tour(profile: str, seed: int, laps: int, shipped: bool = False) -> dict[str, float]:
    """One run of the tour; ``shipped``: the ``sim`` robot's config (its calibrated [geometry]), else the
    drawing's wheels."""
    own = {"sim": {"profile": profile, "seed": seed}}
    if shipped:
        sim = config_mod.load("sim", credentials=False)
        own["geometry"] = {"wheel_diameter": sim.geometry.wheel_diameter, "track": sim.geometry.track}
    config = config_mod.parse(own)
    wheels = realism.wheels(config)
    world = World(config.geometry, seed=seed, slip=wheels.slip, encoder_noise=wheels.encoder_noise, wheels=wheels)
    odometry = make_odometry(config)
    steps_per_sample = round(SAMPLE_S / 0.001)
    t_ns, path, worst = 0, 0.0, 0.0
    odometry.update(0, *world.counts())
    last = world.pose
    for _ in range(laps * 4):
        for left, right, seconds in SIDE:
            world.set_duty(left, right)
            for _ in range(round(seconds / SAMPLE_S)):
                for _ in range(steps_per_sample):
                    world.step(0.001)
                t_ns += round(SAMPLE_S * 1e9)
                odometry.update(t_ns, *world.counts())
                x, y, _ = world.pose
                path += math.hypot(x - last[0], y - last[1])
                last = world.pose
                worst = max(worst, math.hypot(odometry.x - x, odometry.y - y))
    x, y, theta = world.pose
    return {"path_m": path, "final_cm": 100 * math.hypot(odometry.x - x, odometry.y - y), "worst_cm": 100 * worst,
            "heading_deg": math.degrees(abs(wrap_angle(odometry.theta - theta)))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--laps", type=int, default=3, help="laps of the 0.8 m square (default 3)")
    args = parser.parse_args()
    print(f"odometry against the truth, {args.laps} laps of a square, seed {args.seed}:")
    print(f"{'profile':<22} {'path m':>7} {'final cm':>9} {'worst cm':>9} {'heading deg':>12}")
    for label, profile, shipped in (("ideal", "ideal", False), ("realistic", "realistic", False),
                                    ("realistic, calibrated", "realistic", True)):
        r = tour(profile, args.seed, args.laps, shipped)
        print(f"{label:<22} {r['path_m']:>7.2f} {r['final_cm']:>9.2f} {r['worst_cm']:>9.2f} "
              f"{r['heading_deg']:>12.2f}" + ("   (reference)" if profile == "ideal" else ""))


if __name__ == "__main__":
    main()
