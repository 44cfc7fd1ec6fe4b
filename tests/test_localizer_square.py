"""The "done" figures as a pure simulation: the simulator's World driven around a 1 m square four times,
the real odometry model and the real localizer (`icefloe.estimation.localizer`) against the true pose.

Seeded, simulated time: deterministic. Prints the figures (pytest -s shows them).
"""

from __future__ import annotations

import math

import pytest

from icefloe import config as config_mod
from icefloe.estimation.simrun import Scenario, square_run

CONFIG = config_mod.load()


def test_odometry_without_slip_closes_the_square() -> None:
    result = square_run(CONFIG, Scenario(laps=4, side=1.0, seed=1, use_localizer=False))
    print(f"\nno slip, {result.distance:.2f} m driven in {result.sim_seconds:.1f} s: odometry {result.odometry}")
    assert result.distance > 15.5  # the driver really drove 4 x 4 m (plus the turns' wobble)
    assert result.odometry.final_pos < 0.01
    assert result.odometry.final_heading < math.radians(1.0)


def test_localizer_holds_with_slip_noise_and_outliers_while_odometry_drifts() -> None:
    scenario = Scenario(laps=4, side=1.0, seed=1, slip=0.1, encoder_noise=0.02,
                        outlier_rate=0.02, unknown_rate=0.05)
    result = square_run(CONFIG, scenario)
    print(f"\nslip {scenario.slip}, encoder noise {scenario.encoder_noise}, {result.distance:.2f} m: "
          f"odometry {result.odometry}; localizer {result.localizer}; "
          f"sightings {result.sightings}, accepted {result.accepted}, rejected {result.rejected} "
          f"(injected outliers {result.injected_outliers}), unknown {result.unknown}")
    print("position error at the end of each lap, cm: odometry",
          [round(e * 100, 2) for e in result.lap_odometry],
          "localizer", [round(e * 100, 2) for e in result.lap_localizer])
    assert result.localizer.max_pos < 0.05
    assert result.localizer.max_heading < math.radians(3.0)
    # Odometry alone drifts: its error is several centimetres and well above the localizer's.
    assert result.odometry.max_pos > 0.03
    assert result.odometry.max_pos > 2 * result.localizer.max_pos
    # The gate caught the gross errors, and not many good sightings with them.
    assert result.injected_outliers > 20
    assert result.injected_outliers <= result.rejected <= result.injected_outliers + 0.01 * result.sightings
    assert result.unknown > 0


def test_localizer_recovers_from_a_wrong_start() -> None:
    # Told it starts 20 cm and 10 degrees from where it is (with a prior wide enough to admit it).
    scenario = Scenario(laps=1, seed=2, slip=0.05, initial_sigma_xy=0.3, initial_sigma_theta=0.3,
                        initial_error=(0.2, 0.0, math.radians(10)))
    result = square_run(CONFIG, scenario)
    print(f"\nwrong start: localizer {result.localizer}")
    assert result.localizer.max_pos == pytest.approx(0.2, abs=0.03)  # the error it started with
    assert result.localizer.final_pos < 0.03
    assert result.localizer.final_heading < math.radians(2.0)
