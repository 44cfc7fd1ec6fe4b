"""A timed ``/robot/set/velocity?value=V,V&time=T&accel=A`` on the firmware model, in simulated time.

    .venv/bin/python bench/timed_motion_model.py            # errors against V·T, the report's motor and others
    .venv/bin/python bench/timed_motion_model.py --leads    # the lead table of services/webapi/timing.py

What the web API and hwbridge do with a timed motion, step by step on one clock: the web API's
T' (`timing.timed_duration`), hwbridge's profile (`MotionProfile`, re-sent at 50 Hz, ended at its
end), its slew limit and demand dither at 1 kHz, demands written to the board every 5 ms
(``serial_rate_hz``) and the stop (zero demand, integral gains 0) at once; against the PenguinPi
firmware model (`sim/penguinpi_firmware.py`: its 20 ms integer PI loop, the PWM map) driving the
simulated motors (`sim/world.py`). No processes, no wall clock: each case is exact and repeatable,
and the firmware's control phase (where its 20 ms step falls against the motion's start) is a
parameter. `--motor TAU,SLOPE` runs it on another motor than the report's (time constant s,
counts/s per % PWM): the lead depends on the motor, and this shows how much.

The reference (same run): T' = T + the slew's deficit/V, no lead (`timed_duration` with the lead
table at zero), what the table makes up.
"""

from __future__ import annotations

import argparse
import math
import statistics
from collections.abc import Callable
from dataclasses import dataclass

from icefloe.config import Geometry
from icefloe.services.hwbridge.control import DemandDither, MotionProfile, SlewLimiter
from icefloe.services.webapi import timing
from icefloe.sim.penguinpi_firmware import PenguinPiFirmware
from icefloe.sim.world import MOTOR_TAU, SLOPE_COUNTS_PER_PCT, World

GEOMETRY = Geometry()
UNIT = 10 * math.pi * GEOMETRY.wheel_diameter / GEOMETRY.ticks_per_rev
"""m/s per firmware demand unit."""
MAX_SPEED = 0.5
MAX_ACCEL = 2.0
"""hwbridge's defaults: ``max_wheel_speed`` (m/s), ``max_accel`` (m/s²)."""
STEP_MS = 20
"""hwbridge re-sends a timed motion's speeds every 20 ms (`bridge.MOTION_STEP_S`)."""
EXCHANGE_MS = 5
"""A wheel exchange with the board every 5 ms (``serial_rate_hz`` 200)."""
LINE_MS = 2
"""A request reaches the firmware ~1.5 ms after it is written (7 bytes at 115200 baud and the reply)."""
PHASES = (0, 5, 10, 15)
"""Where the firmware's 20 ms control step falls, ms after the motion's start: the mean of these."""
DEMANDS = (10, 20, 40, 65, 90)
TIMES = (0.5, 1.0, 3.0, 5.0)


@dataclass(frozen=True)
class Motor:
    tau: float = MOTOR_TAU
    """First-order time constant, s."""
    slope: float = SLOPE_COUNTS_PER_PCT
    """Steady counts/s per % PWM at the nominal voltage."""


def held(demand: float, t: float, accel: float, lead: bool = True) -> float:
    """T' as the web API sends it (``lead=False``: without the lead table)."""
    duration = timing.timed_duration(demand, demand, t, accel, unit=UNIT, max_speed=MAX_SPEED,
                                     max_accel=MAX_ACCEL)
    return duration + (0.0 if lead else timing.lead(demand, accel, t))


def drive(demand: float, duration: float, accel: float, *, motor: Motor = Motor(), phase_ms: int = 0,
          settle_s: float = 0.6) -> float:
    """Metres the robot's truth moves for a timed motion of ``demand`` held ``duration`` (T') s."""
    world = World(GEOMETRY, seed=1, motor_tau=motor.tau, counts_per_pct=motor.slope)
    firmware = PenguinPiFirmware(world)
    for wheel in (firmware.left, firmware.right):
        wheel.kvi = 0  # hwbridge holds the integral gain at 0 while stopped
    for _ in range(phase_ms % 20):
        firmware.tick(0.0)  # the firmware's control step falls phase_ms into each 20 ms
    slew, dither = SlewLimiter(MAX_ACCEL), DemandDither(GEOMETRY)
    profile = MotionProfile(demand * UNIT, demand * UNIT, duration, accel, 0.0)
    end_ms = math.ceil(round(profile.end * 1000, 6))
    sent: tuple[int, int, int] | None = None  # (ms it arrives, demand, integral gain)
    speed, ms, last = 0.0, 0, end_ms + round(settle_s * 1000)
    while ms < last:
        ms += 1
        world.step(0.001)
        firmware.tick(ms / 1000)
        if sent is not None and sent[0] <= ms:
            for wheel in (firmware.left, firmware.right):
                wheel.demand, wheel.kvi = sent[1], sent[2]
            sent = None
        if ms == end_ms:  # the motion's end: a latched stop, sent to the board at once
            slew.reset()
            dither.step(0.0, 0)
            sent = (ms + LINE_MS, 0, 0)
        elif ms < end_ms:
            if (ms - 1) % STEP_MS == 0:
                speed = profile.at((ms - 1) / 1000)[0]
            target = slew.step(speed, 0.001)
            demand_now = dither.step(target, ms * 1_000_000)
            if ms % EXCHANGE_MS == 0 and sent is None:
                sent = (ms + LINE_MS, demand_now, 1 if target else 0)
    x, y, _ = world.pose
    return math.copysign(math.hypot(x, y), x)


def error(demand: float, t: float, accel: float, *, motor: Motor = Motor(), lead: bool = True,
          phases: tuple[int, ...] = PHASES) -> list[float]:
    """Relative error against V·T, one per firmware phase."""
    want = demand * UNIT * t
    return [drive(demand, held(demand, t, accel, lead), accel, motor=motor, phase_ms=p) / want - 1 for p in phases]


def run_on_ms(demand: float, t: float, accel: float, lead_ms: float) -> float:
    """How much further than V·T (ms of V, the mean over `PHASES`) a motion held for T' less
    ``lead_ms`` goes."""
    duration = held(demand, t, accel, lead=False) - lead_ms / 1000
    want = demand * UNIT * t
    return statistics.mean(drive(demand, duration, accel, phase_ms=p) / want - 1 for p in PHASES) * t * 1000


def leads(show: Callable[[str], None] = print, rounds: int = 5) -> None:
    """The table of `timing.LEAD_MS`: the lead (ms of V) with which a motion covers V·T on the
    firmware model. A shorter hold does not lose quite V·lead (a short motion's wheels never
    reached V), so the lead is found in ``rounds`` secant steps, each at most 20 ms and all within
    30 ms of the first guess (the run-on moves in steps of the firmware's control period, and at
    10-15 units in the dead band, where a free secant would leap)."""
    show("LEAD_MS: tuple[tuple[tuple[float, ...], ...], ...] = (  # bench/timed_motion_model.py --leads")
    for t in timing.LEAD_TIMES:
        show(f"    (  # T = {t:g} s; rows: LEAD_DEMANDS, columns: LEAD_ACCELS")
        for demand in timing.LEAD_DEMANDS:
            row = []
            for accel in timing.LEAD_ACCELS:
                fits = min((x for x in timing.LEAD_TIMES if x > 2 * accel + 0.05), default=2 * accel + 0.5)
                run = max(t, fits)
                most = 1000 * (held(demand, run, accel, lead=False) - 2 * accel) - 2  # the profile needs T' > 2A
                a, fa = 0.0, run_on_ms(demand, run, accel, 0.0)
                fa_0, b = fa, min(fa, most)
                best = (abs(fa), a)
                for _ in range(rounds):
                    fb = run_on_ms(demand, run, accel, b)
                    best = min(best, (abs(fb), b))
                    if abs(fb) < 0.2:
                        break
                    slope = (fb - fa) / (b - a) if b != a else -1.0
                    step = -fb / slope if slope < -0.2 else fb  # a flat or wrong-way piece: a plain step
                    # within 30 ms of the first guess: the dead band at 10-15 units has flat pieces
                    a, fa, b = b, fb, min(most, fa_0 + 30, max(fa_0 - 30, b + max(-20.0, min(20.0, step))))
                row.append(best[1])
            show("        (" + ", ".join(f"{ms:.1f}" for ms in row) + f"),  # {demand}")
        show("    ),")
    show(")")


def table(motor: Motor, accels: tuple[float, ...], show: Callable[[str], None] = print) -> None:
    show(f"motor: tau {motor.tau} s, {motor.slope} counts/s per % PWM")
    show("demand  accel  " + "  ".join(f"{f'T={t:g} s':>22}" for t in TIMES))
    for accel in accels:
        for demand in DEMANDS:
            cells = []
            for t in TIMES:
                if accel and t <= 2 * accel:
                    cells.append(f"{'-':>22}")
                    continue
                now, before = error(demand, t, accel, motor=motor), error(demand, t, accel, motor=motor, lead=False)
                cells.append(f"{100 * statistics.mean(now):+5.1f} ±{50 * (max(now) - min(now)):.1f}"
                             f" ({100 * statistics.mean(before):+5.1f}) %")
            show(f"{demand:6d}  {accel:5.2f}  " + "  ".join(cells))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--leads", action="store_true", help="print the lead table of services/webapi/timing.py")
    parser.add_argument("--motor", action="append", default=[], metavar="TAU,SLOPE",
                        help="also a motor with this time constant (s) and counts/s per %% PWM (repeatable)")
    parser.add_argument("--accel", default="0,0.2", help="ramp times A to show, s (default 0,0.2)")
    args = parser.parse_args()
    if args.leads:
        leads()
        return
    accels = tuple(float(a) for a in args.accel.split(","))
    print("error against V·T: mean over the firmware's control phases ±half their spread "
          "(in brackets: T' without the lead table)")
    for motor in [Motor()] + [Motor(*(float(v) for v in m.split(","))) for m in args.motor]:
        table(motor, accels)


if __name__ == "__main__":
    main()
