"""A timed ``/robot/set/velocity?value=V,V&time=T`` (and ``&accel=A``) covers V·T on the simulator's
truth, at speeds from low to high, forward and back, unramped and ramped (docs/webapi.md, timed
motion; bench/timed_motion.py has the full table). Real sim, hwbridge and webapi processes. About
60 s.

T is 3 s: the start and stop of a motion each wander by ~10 ms on a loaded machine (the bus, the
serial exchange, the firmware's 20 ms control step), 0.3 % of 3 s; at 1 s the same wander is 1 %.
Shorter motions are checked on the firmware model in simulated time (test_timed_motion_model.py).
That is where the 1 % goal is held; here, on real processes of a machine as busy as CI's (load
10-19), a run is redone while it is more than 1 % off, and the last must be within `REAL_BOUND`
(one motion of five was 1.0-1.4 % off at load 10-19 on 2026-12-07, every other within 1 %).
"""

from __future__ import annotations

import asyncio
import math
import time

import pytest
from webapi_helpers import K, board, still, webapi, webapi_robot

from icefloe.services.webapi import timing

T = 3.0
REAL_BOUND = 0.015
"""How far from V·T a motion of real processes may end, the third run of a motion more than 1 % off."""


@pytest.fixture
def robot(make_robot):
    # ideal: the subject is the motion's timing (V·T), not the wheels' sizes, which a realistic robot's
    # own calibration makes up for (docs/webapi.md, timed motion)
    return webapi_robot(make_robot, '[sim]\nprofile = "ideal"\n')


async def test_timed_motions_cover_v_times_t_across_speeds(robot):
    for service in ("sim", "hwbridge"):
        robot.start(service)
    async with webapi(robot) as http, robot.node("tester") as node:
        async def encoders_up() -> bool:
            return (await http.get("/robot/get/encoder"))[0] == 200
        for _ in range(300):
            if await encoders_up():
                break
            await asyncio.sleep(0.1)
        scales = {}
        for demand, accel in ((15, 0.0), (-40, 0.0), (80, 0.0), (40, 0.2), (-65, 0.5)):
            want = demand * K * T
            for _ in range(3):
                before, wall = await still(node), time.monotonic()
                status, _, body = await http.get("/robot/set/velocity", value=f"{demand},{demand}", time=str(T),
                                                 accel=str(accel))
                assert status == 200, body
                after = await still(node)
                moved = ((after.x - before.x) * math.cos(before.theta)
                         + (after.y - before.y) * math.sin(before.theta))
                # hwbridge times the motion by the wall clock; a simulator starved of CPU drops steps
                # (its time runs slow) and its robot covers less: then that run says nothing. Again; and
                # once more when a busy machine held the start or the stop back (runs of one motion differ
                # by up to a few % there: docs/webapi.md); an error of the timing itself fails every time.
                starved = after.sim_time - before.sim_time < 0.995 * (time.monotonic() - wall)
                if not starved and abs(moved / want - 1) < 0.01:
                    break
            assert abs(after.theta - before.theta) < 0.02  # both wheels alike: straight
            assert moved == pytest.approx(want, rel=REAL_BOUND), \
                f"{demand}, accel {accel}: {moved:.4f} m of {want:.4f} m"
            if not accel:
                scales[demand] = moved / (demand * T)  # m per (demand unit · s), as a wheel calibration finds it
        # A course's wheel calibration (timed drives at several speeds) finds one scale.
        assert max(scales.values()) / min(scales.values()) - 1 < 0.015, scales




async def test_the_motion_sent_makes_up_for_hwbridges_slew_limit(make_robot):
    """What `cmd/motion` the web API sends for a timed request (a stand-in hwbridge on the bus)."""
    def lead(demand: float, accel: float, t: float) -> float:
        return timing.lead(demand, accel, t)

    cases = [  # the request, and T' as the web API works it out
        # V/2a for hwbridge's slew, less the run-on (timing.LEAD_MS)
        ({"value": "40,40", "time": "0.3"}, 0.3 + 40 * K / 4 - lead(40, 0.0, 0.3)),
        # V as hwbridge limits it: 0.5 m/s
        ({"value": "100,-100", "time": "0.3"}, 0.3 + 0.5 / 4 - lead(0.5 / K, 0.0, 0.3)),
        ({"value": "90,90", "time": "0.5", "accel": "0.1"},
         0.5 + (90 * K - 0.2) ** 2 / (4 * 90 * K) - lead(90, 0.1, 0.5)),
        # a ramp gentler than 2 m/s²: as asked, less the run-on
        ({"value": "20,20", "time": "0.6", "accel": "0.2"}, 0.6 - lead(20, 0.2, 0.6)),
        ({"value": "0,0", "time": "0.3"}, 0.3),
    ]
    robot = webapi_robot(make_robot)
    async with webapi(robot) as http, board(robot) as b:
        for query, sent in cases:
            status, _, body = await http.get("/robot/set/velocity", **query)
            assert status == 200, body
            motion = b.motions[-1]
            assert motion.duration == pytest.approx(sent, abs=1e-9), query
            assert motion.accel == float(query.get("accel", 0.0))
