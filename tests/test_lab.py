"""A lab: one lab router (`icefloe router --lab`), three simulated robots, laptops with credentials.

Real processes throughout: the lab router, and per robot its own router joined to the
lab router (``[zenoh] lab``, docs/lab.md) and ``services.sim`` + ``services.hwbridge`` +
``services.odometry`` with access control on. The
harness is the one ``bench/lab_scale.py`` runs with ten robots; here we assert
on what it saw. The checks are about behaviour (who may drive whom, every
robot heard); the rate check is relative to each robot's own configured rate.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from conftest import ROOT

sys.path.insert(0, str(ROOT / "bench"))
import lab_scale  # the bench script is the harness

pytestmark = pytest.mark.slow


async def test_a_lab_router_keeps_robots_apart(tmp_path: Path) -> None:
    with lab_scale.Lab(tmp_path, robots=3, mesh=True) as lab:
        lab.start_router()
        report = await lab_scale.measure(lab, seconds=4.0, start_timeout=45.0)
        assert lab.router.alive(), "the lab router died"
    assert lab.killed == [], "these did not stop on SIGINT"
    own_a, own_b = report.driven
    intruded = report.intruded
    robots = report.robots

    # The laptop sees every robot, with each of its services, through the one lab router.
    for name in lab.names:
        assert {"sim", "hwbridge", "odometry"} <= report.seen[name], name

    # Each robot's own credentials drive it (0.15 m/s for 4 s is about 0.6 m) ...
    assert robots[own_a].moved_m > lab_scale.MOVED_M
    assert robots[own_b].moved_m > lab_scale.MOVED_M
    assert robots[own_a].twists_heard > 0 and robots[own_b].twists_heard > 0  # a guest sees them pass

    # ... but robot A's credentials do not drive robot C: the lab router drops every twist.
    assert robots[intruded].twists_sent > 0
    assert robots[intruded].twists_heard == 0
    for r in robots.values():  # and no robot but the two driven ones moved
        if r.name not in report.driven:
            assert r.moved_m < lab_scale.STILL_M, (r.name, r.role, r.moved_m)

    # Every robot's pose reaches the laptop at (nearly) the rate its config asks for.
    for r in robots.values():
        assert r.configured_hz == lab.config(r.name).odometry.rate_hz
        assert r.rate_hz >= lab_scale.MIN_RATE * r.configured_hz, (r.name, r.rate_hz, r.configured_hz)


async def test_a_robot_router_joins_the_lab_router_whenever_it_is_up(tmp_path: Path) -> None:
    """The robot boots before the lab machine, and the TA restarts the lab router after adding
    a robot: each time, the robot's router (re)joins by itself."""
    import asyncio
    import time

    from lab_harness import Lab
    from lab_scale import guest_config

    from icefloe.runtime import Node
    from icefloe.schemas import keys

    async def joined(lab: Lab, timeout: float = 30.0) -> None:
        async with Node("laptop", guest_config(lab.endpoint), announce=False, retry=False) as guest:
            deadline = time.monotonic() + timeout
            while keys.alive_key(lab.names[0], "router") not in await guest.alive("*"):
                assert time.monotonic() < deadline, "the robot's router did not join"
                await asyncio.sleep(0.3)

    with Lab(tmp_path, robots=1, mesh=True) as lab:
        lab.start_robot(lab.names[0], services=[])  # its router only, before the lab router
        await asyncio.sleep(1.0)
        lab.start_router()
        await joined(lab)
        lab.router.interrupt()
        assert lab.router.wait(10)
        lab.start_router()
        await joined(lab)
    assert lab.killed == []
