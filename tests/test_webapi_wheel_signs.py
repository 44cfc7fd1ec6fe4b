"""``[webapi] wheel_signs``: a fleet's old clients that turn a wheel round drive straight.

ECE4078's 2023 client (``util/pibot.py``, class ``PenguinPi``) negates the right wheel's speed
whenever its ``ip`` is not ``'localhost'`` ("running on physical robot (if right wheel spins
backwards in test motor)"); on a robot whose wheels turn the way they are told, that spins it in
place. Here that client's own ``set_velocity``, unchanged (`course_clients`), drives the simulated
robot through two web APIs of one robot: one as shipped (its ``'localhost'`` path, the course's
simulator path, drives straight; its robot path spins) and one with ``wheel_signs = [1, -1]`` (its
robot path drives straight and turns the way the simulator path does). The simulator's truth
judges. A bad value starts nothing and says why in one line.

About 35 s on a busy 2-core machine (sim, hwbridge, odometry and two webapi processes).
"""

from __future__ import annotations

import asyncio
import math
import subprocess
import sys
from pathlib import Path

import aiohttp
import pytest
from conftest import Proc, free_port
from course_clients import ece4078_client
from webapi_helpers import K, still, webapi, webapi_robot

from icefloe.config import ConfigError
from icefloe.config import load as load_config
from icefloe.errors import EXIT_CONFIG
from icefloe.schemas import messages as m


@pytest.mark.parametrize("value", ["[1, 0]", "[-1]", "[1, -1, 1]", '"right"', "[1.0, -1]", "[-2, 1]"])
def test_a_bad_value_is_refused_in_one_line(tmp_path: Path, value: str) -> None:
    cfg = tmp_path / "fleet.toml"
    cfg.write_text(f'extends = "sim"\nname = "fleet"\n[webapi]\nwheel_signs = {value}\n')
    with pytest.raises(ConfigError) as refused:
        load_config(cfg)
    assert str(refused.value).startswith(f"{cfg}: webapi.wheel_signs"), refused.value
    assert "\n" not in str(refused.value)


def test_the_service_starts_nothing_with_a_bad_value(tmp_path: Path) -> None:
    port = free_port()
    cfg = tmp_path / "fleet.toml"
    cfg.write_text(f'extends = "sim"\nname = "fleet{port}"\nrun_dir = "{tmp_path}/run"\n'
                   f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\nconnect = ["tcp/127.0.0.1:{port}"]\n'
                   f'[webapi]\nhost = "127.0.0.1"\nport = {free_port()}\nwheel_signs = [1, 0]\n')
    res = subprocess.run([sys.executable, "-m", "icefloe.services.webapi", "--config", str(cfg)],
                         capture_output=True, text=True, timeout=60)
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    line = lines[0]
    assert res.returncode == EXIT_CONFIG, res.stderr
    assert "webapi.wheel_signs[1]" in line and "0" in line, line


def motion(before: m.SimState, after: m.SimState) -> tuple[float, float]:
    """(forward m along the start heading, turn rad CCW) from one state to the other."""
    forward = (after.x - before.x) * math.cos(before.theta) + (after.y - before.y) * math.sin(before.theta)
    return forward, math.remainder(after.theta - before.theta, math.tau)


async def test_ece4078_2023s_set_velocity_drives_straight_on_both_paths(make_robot, tmp_path: Path) -> None:
    pibot = ece4078_client(tmp_path)
    robot = webapi_robot(make_robot)  # its web API as shipped: wheel_signs = [1, 1]
    for service in ("sim", "hwbridge", "odometry"):
        robot.start(service)
    fleet_port = free_port()  # a second web API of the same robot, as a fleet with the setting has it
    fleet_cfg = robot.tmp / "fleet.toml"
    fleet_cfg.write_text(f'extends = "{robot.config_path}"\n[webapi]\nport = {fleet_port}\nwheel_signs = [1, -1]\n')
    fleet = Proc("webapi-fleet", [sys.executable, "-m", "icefloe.services.webapi", "--config", str(fleet_cfg)],
                 robot.tmp / "webapi-fleet.log", robot.env)
    robot.procs.append(fleet)
    shipped_port = robot.config.webapi.port
    async with webapi(robot) as http, robot.node("tester") as node, aiohttp.ClientSession() as session:
        for _ in range(300):  # both web APIs answer, hwbridge's counts have come
            try:
                async with session.get(f"http://127.0.0.1:{fleet_port}/robot/get/encoder") as r:
                    if r.status == 200 and (await http.get("/robot/get/encoder"))[0] == 200:
                        break
            except aiohttp.ClientConnectionError:
                assert fleet.alive(), fleet.output
            await asyncio.sleep(0.1)

        async def drive(ip: str, port: int, command: list[int], time: float = 1.0) -> tuple[float, float]:
            """The client's own set_velocity (a timed motion: it blocks until the robot has stopped)."""
            before = await still(node)
            client = pibot.PenguinPi(ip, port)
            await asyncio.to_thread(client.set_velocity, command, time=time)
            return motion(before, await still(node))

        async def encoders(port: int) -> tuple[int, int]:
            async with session.get(f"http://127.0.0.1:{port}/robot/get/encoder") as r:
                left, right = (await r.text()).split(",")
                return int(left), int(right)

        straight = 50 * K * 1.0  # tick = 50 demand units for 1 s
        # The simulator path ('localhost') on the web API as shipped: straight.
        forward, turn = await drive("localhost", shipped_port, [1, 0])
        assert forward == pytest.approx(straight, rel=0.05) and abs(turn) < 0.03, (forward, turn)
        # The robot path on the web API as shipped: the right wheel backwards, the robot spins in place.
        forward, turn = await drive("127.0.0.1", shipped_port, [1, 0], time=0.5)
        assert abs(forward) < 0.02 and turn < -1.0, (forward, turn)  # clockwise, 2V·T/track = 1.7 rad

        # The robot path with wheel_signs = [1, -1]: straight, and a turn the way the simulator path turns.
        counts_before = await encoders(fleet_port)
        forward, turn = await drive("127.0.0.1", fleet_port, [1, 0])
        assert forward == pytest.approx(straight, rel=0.05) and abs(turn) < 0.03, (forward, turn)
        counts = await encoders(fleet_port)
        # The counts come back as that fleet's robots counted: the right wheel's negated.
        assert counts[0] - counts_before[0] > 300 and counts[1] - counts_before[1] < -300, (counts_before, counts)
        _, left_turn = await drive("127.0.0.1", fleet_port, [0, 1])
        _, sim_turn = await drive("localhost", shipped_port, [0, 1])
        assert left_turn > 0.3 and left_turn == pytest.approx(sim_turn, rel=0.1), (left_turn, sim_turn)

        # Its other path, a held speed (time=0): straight until the next command.
        before = await still(node)
        client = pibot.PenguinPi("127.0.0.1", fleet_port)
        await asyncio.to_thread(client.set_velocity, [1, 0])
        await asyncio.sleep(0.6)
        async with session.get(f"http://127.0.0.1:{fleet_port}/robot/stop") as r:
            assert r.status == 200, await r.text()
        forward, turn = motion(before, await still(node))
        assert forward > 0.1 and abs(turn) < 0.03, (forward, turn)
    assert fleet.stop() == 0, fleet.output
