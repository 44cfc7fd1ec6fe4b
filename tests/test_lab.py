"""A lab: one lab router (`icefloe router --lab`), three simulated robots, laptops with credentials.

Real processes throughout: the lab router, and per robot its own router joined to the
lab router (``[zenoh] lab``, docs/lab.md) and ``services.sim`` + ``services.hwbridge`` +
``services.odometry`` with access control on. The
harness is the one ``bench/lab_scale.py`` runs with ten robots; here we assert
on what it saw. The checks are about behaviour (who may drive whom, every
robot heard); the rate check is relative to each robot's own configured rate.
"""

from __future__ import annotations

import shutil
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


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is not installed")
async def test_a_robot_router_joins_its_lab_over_tls(tmp_path: Path) -> None:
    """`lab = ["tls/..."]`: the robot's router checks the lab router's certificate (no one can pose
    as the lab machine) and the lab link is recognised by its protocol, tls, as it is by ws."""
    import asyncio
    import contextlib
    import time

    from conftest import free_port
    from lab_harness import SIM_CONFIG, Proc, _wait_listening
    from lab_scale import guest_config, laptop_config
    from test_access import make_certificates

    from icefloe import config as config_mod
    from icefloe.credentials import make
    from icefloe.runtime import Node
    from icefloe.schemas import keys
    from icefloe.schemas import messages as m

    make_certificates(tmp_path)  # a lab CA, and a certificate for localhost
    laptops, uplink, robot_port = free_port(), free_port(), free_port()
    creds, _ = make(tmp_path / "lab" / "tlsbot.credentials", "tlsbot")
    (tmp_path / "lab.toml").write_text(
        f'name = "lab"\nrun_dir = "{tmp_path / "run-lab"}"\n[zenoh]\n'
        f'listen = ["tcp/127.0.0.1:{laptops}", "tls/127.0.0.1:{uplink}"]\nconnect = []\n'
        f'tls_certificate = "{tmp_path}/robot.pem"\ntls_private_key = "{tmp_path}/robot.key"\n')
    (tmp_path / "tlsbot.toml").write_text(
        f'extends = "{SIM_CONFIG}"\nname = "tlsbot"\nrun_dir = "{tmp_path / "run-bot"}"\n[zenoh]\n'
        f'listen = ["tcp/127.0.0.1:{robot_port}"]\nconnect = ["tcp/127.0.0.1:{robot_port}"]\n'
        f'lab = ["tls/localhost:{uplink}"]\ntls_root_ca = "{tmp_path}/ca.pem"\n'
        f'access_control = true\ncredentials = "{creds}"\n')
    lab = Proc("lab router", [sys.executable, "-m", "icefloe.cli", "router", str(tmp_path / "lab.toml"),
                              "--lab", str(tmp_path / "lab")], tmp_path / "lab.log")
    bot = Proc("tlsbot/router", [sys.executable, "-m", "icefloe.router", "--config", str(tmp_path / "tlsbot.toml")],
               tmp_path / "tlsbot.log")
    try:
        _wait_listening(lab, 20)
        _wait_listening(bot, 20)
        robot = config_mod.load(tmp_path / "tlsbot.toml")
        endpoint = f"tcp/127.0.0.1:{laptops}"
        async with Node("hwbridge-stand-in", robot) as service, \
                Node("laptop", laptop_config(creds, endpoint), announce=False) as owner, \
                Node("laptop", guest_config(endpoint), announce=False) as guest:
            twists = service.subscribe(keys.TWIST)
            deadline = time.monotonic() + 30
            while keys.alive_key("tlsbot", "hwbridge-stand-in") not in await guest.alive("*"):
                assert time.monotonic() < deadline, f"not joined:\n{bot.tail()}"
                await asyncio.sleep(0.3)
            pub = owner.publisher(keys.TWIST)
            for _ in range(50):  # until the twist arrives through the lab router and the tls link
                pub.put(m.Twist(v=0.1, w=0.0))
                with contextlib.suppress(TimeoutError):
                    assert (await asyncio.wait_for(twists.__anext__(), 0.2)).v == 0.1
                    break
            else:
                raise AssertionError("the owner's twist did not reach the robot over the tls lab link")
            guest.session.put(keys.key("tlsbot", keys.TWIST), b'{"v": 0.3, "w": 0}')  # and the guest's did not
            await asyncio.sleep(1.0)
            while twists.pending():
                assert (await twists.__anext__()).v == 0.1
    finally:
        for proc in (bot, lab):
            proc.interrupt()
            proc.wait(10)
