"""The realistic profile's wheels and motors (`icefloe.sim.realism`, `sim/world.py`): each effect does
what its key says, the ideal profile is the simulator as it was, and the table in docs/sim.md is
`realism.EFFECTS`. Pure computation, no processes: about 3 s in all."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from icefloe import config as config_mod
from icefloe.config import Geometry
from icefloe.sim import realism
from icefloe.sim.world import NOMINAL_VOLTAGE, World

GEOM = Geometry()
IDEAL = config_mod.parse({"sim": {"profile": "ideal"}})
M_PER_COUNT = math.pi * GEOM.wheel_diameter / GEOM.ticks_per_rev
DOCS = Path(__file__).resolve().parent.parent / "docs" / "sim.md"


def run(world: World, seconds: float) -> None:
    for _ in range(round(seconds / 0.001)):
        world.step(0.001)


def wheels(*, noise: bool = True, **own: object) -> realism.Wheels:
    """The realistic profile's wheels with ``own`` keys of ``[sim.wheels]`` set (the rest: the table's);
    without ``noise``, no random slip or encoder noise (``[sim] slip``, ``encoder_noise``)."""
    quiet = {} if noise else {"slip": 0.0, "encoder_noise": 0.0}
    return realism.wheels(config_mod.parse({"sim": {"profile": "realistic", "wheels": own, **quiet}}))


def test_the_profiles_resolve_and_an_own_key_wins():
    ideal = realism.wheels(IDEAL)
    assert config_mod.parse({}).sim.profile == "realistic"  # the default
    assert (ideal.diameter_left, ideal.diameter_right, ideal.track) == (GEOM.wheel_diameter,) * 2 + (GEOM.track,)
    assert (ideal.slip_accel, ideal.slip_turn, ideal.slip, ideal.encoder_noise) == (0.0, 0.0, 0.0, 0.0)
    real = wheels()
    assert (real.diameter_left, real.diameter_right, real.track) == (0.0642, 0.0638, 0.1535)
    assert real.dead_band_left == 11.0 and real.slip == 0.05
    assert wheels(track=0.15).track == 0.15
    # the old keys [sim] slip and encoder_noise still win over the profile, as the tests set them
    own = realism.wheels(config_mod.parse({"sim": {"profile": "realistic", "slip": 0.0, "encoder_noise": 0.02}}))
    assert own.slip == 0.0 and own.encoder_noise == 0.02
    assert realism.picture(IDEAL) == realism.Picture()  # ideal: the renderer as it was
    with pytest.raises(config_mod.ConfigError, match="profile"):
        config_mod.parse({"sim": {"profile": "kind"}})


def test_the_ideal_profile_moves_the_robot_exactly_as_before():
    before = World(GEOM, seed=3)
    now = World(GEOM, seed=3, wheels=realism.wheels(IDEAL))
    for duties in ((0.5, 0.3), (-0.4, 0.6), (0.05, 0.2), (0.0, 0.0)):
        for w in (before, now):
            w.set_duty(*duties)
            run(w, 0.4)
        assert now.pose == before.pose and now.counts() == before.counts()
        assert now.wheel_speeds == before.wheel_speeds


def test_true_wheels_and_track_make_odometry_wrong_by_their_ratio():
    """No slip: the ground a wheel covers is its true size over the believed one, and the heading
    follows the true track (0.1535 m against the believed 0.156 m: turns 1.6 % further)."""
    true = wheels(noise=False, slip_accel=0.0, slip_turn=0.0, dead_band_left=9.0)
    world = World(GEOM, seed=1, wheels=true)
    world.set_duty(-0.5, 0.5)  # spin in place
    run(world, 1.0)
    left, right = world.counts()
    believed = (right - left) * M_PER_COUNT / GEOM.track
    turned = (right * true.diameter_right - left * true.diameter_left) / GEOM.wheel_diameter * M_PER_COUNT / true.track
    assert world.pose[2] == pytest.approx(math.remainder(turned, math.tau), abs=0.008)  # counts are whole: 0.0035 rad
    assert turned / believed == pytest.approx(0.0640 / 0.065 * 0.156 / 0.1535, rel=0.01)
    # the true speed of each wheel is its turning times its true size
    assert world.wheel_speeds[1] / world.wheel_speeds[0] == pytest.approx(-0.0638 / 0.0642, rel=1e-3)
    v, w = world.velocity
    assert abs(v) < 0.005 and w > 0  # the wheels differ by 0.6 %: the spin creeps 1 mm/s


def test_each_motor_has_its_own_dead_band():
    world = World(GEOM, seed=1, wheels=wheels())  # left 11 %, right 9 %
    world.set_duty(0.10, 0.10)
    run(world, 0.5)
    left, right = world.counts()
    assert left == 0 and right > 0 and world.pose[2] > 0  # the start pulls to the left


def test_a_start_slips_by_its_acceleration():
    """slip_accel 0.03 s²/m: a start at 80 % duty loses 3 % of a wheel's travel per m/s² of its acceleration
    (measured: 3.5 % of the first 0.3 s, 11 cm)."""
    def travelled(slip_accel: float) -> tuple[float, float]:
        true = wheels(noise=False, slip_accel=slip_accel, slip_turn=0.0, diameter_left=0.065, diameter_right=0.065,
                      dead_band_left=9.0)
        world = World(GEOM, seed=1, wheels=true)
        world.set_duty(0.8, 0.8)
        run(world, 0.3)
        return world.pose[0], world.counts()[0] * M_PER_COUNT
    grip, counted = travelled(0.0)
    slipped, counted_too = travelled(0.03)
    assert counted_too == pytest.approx(counted)           # the wheels turned as much
    lost = 1 - slipped / grip
    print(f"a start at 80 % duty: {lost:.1%} of {grip * 100:.1f} cm lost")
    assert 0.02 < lost < 0.07                               # measured: 3.5 % of the start's 11 cm
    assert grip == pytest.approx(counted, rel=0.01)


def test_a_fast_turn_scrubs():
    def turned(slip_turn: float) -> float:
        world = World(GEOM, seed=1, wheels=wheels(noise=False, slip_accel=0.0, slip_turn=slip_turn,
                                                  dead_band_left=9.0))
        world.set_duty(-0.6, 0.6)
        run(world, 1.0)
        return world.velocity[1]
    free, scrubbed = turned(0.0), turned(0.02)
    assert scrubbed == pytest.approx(free * (1 - 0.02 * free), rel=0.01)   # 2 % per rad/s


def test_without_battery_sag_the_speed_ignores_the_voltage():
    sag = World(GEOM, seed=1, wheels=wheels())
    flat = World(GEOM, seed=1, wheels=wheels(battery_sag=False))
    for w in (sag, flat):
        w.set_battery_voltage(6.4)
    assert sag.steady_speed(0.5) == pytest.approx(flat.steady_speed(0.5) * sag._terminal_voltage() / NOMINAL_VOLTAGE)
    assert flat.steady_speed(0.5) == pytest.approx(11.5 * 50 * M_PER_COUNT)


def shown(value: object) -> str:
    """An effect's value as docs/sim.md's table shows it."""
    if value == realism.NOMINAL:
        return "as believed"
    return f"`{str(value).lower() if isinstance(value, bool) else value}`"


def test_the_docs_table_is_the_effects_table():
    """docs/sim.md's table of effects lists every key of `realism.EFFECTS`, with both profiles' values."""
    text = DOCS.read_text()
    rows = {m[1]: (m[2].strip(), m[3].strip())
            for m in re.finditer(r"^\| `([a-z_.]+)` \| ([^|]*) \| ([^|]*) \|", text, re.MULTILINE)}
    assert {key: rows.get(key) for key in (e.key for e in realism.EFFECTS)} == \
        {e.key: (shown(e.ideal), shown(e.realistic)) for e in realism.EFFECTS}


def test_a_course_wheel_calibration_finds_the_true_scale_and_track():
    """What a course does with its robot (ECE4078's calibration): drive straight and measure the distance
    (here the truth) for the scale, m per count; spin and measure the angle for the baseline. In the
    realistic profile both find the true wheels, not the drawing's: the scale the mean true wheel's (the
    start's slip a little short), the baseline the true track lengthened by what the turn scrubs,
    track / (1 - slip_turn x w). Measured (seed 2): scale 0.28 % under the true wheels', 1.8 % under
    the drawing's; baseline 0.1643 m spinning at 3.2 rad/s, against 0.1535 / (1 - 0.02 x 3.2) = 0.1640
    (and the drawing's 0.156)."""
    true = wheels()
    ideal_scale = M_PER_COUNT
    true_scale = M_PER_COUNT * (true.diameter_left + true.diameter_right) / 2 / GEOM.wheel_diameter
    world = World(GEOM, seed=2, slip=true.slip, encoder_noise=true.encoder_noise, wheels=true)
    world.set_duty(0.5, 0.5)
    run(world, 3.0)
    world.set_duty(0.0, 0.0)
    run(world, 0.5)
    left, right = world.counts()
    scale = math.hypot(*world.pose[:2]) / ((left + right) / 2)
    world.set_pose(0.0, 0.0, 0.0)
    start = world.counts()
    world.set_duty(-0.4, 0.4)
    run(world, 0.6)  # about 2 rad: the heading stays within ±π
    w = world.velocity[1]
    world.set_duty(0.0, 0.0)
    run(world, 0.5)
    left, right = (c - s for c, s in zip(world.counts(), start, strict=True))
    baseline = (right - left) * scale / world.pose[2]
    print(f"\nscale {scale * 1e3:.5f} mm/count: true wheels' {true_scale * 1e3:.5f}, "
          f"drawing's {ideal_scale * 1e3:.5f}; "
          f"baseline {baseline:.4f} m at {w:.1f} rad/s: track {true.track} / (1 - {true.slip_turn} x w) = "
          f"{true.track / (1 - true.slip_turn * w):.4f}, drawing {GEOM.track}")
    assert scale == pytest.approx(true_scale, rel=0.006) and abs(scale / ideal_scale - 1) > 0.01
    assert baseline == pytest.approx(true.track / (1 - true.slip_turn * w), rel=0.01)
