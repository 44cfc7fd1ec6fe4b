"""A TA's handles on the simulated robot (``sim/control``: place, reset, pause, resume), from the
bus, the CLI and the HTTP bus bridge; who may use them (the owner, the lab's TA account; nobody
else); what odometry does when the robot is placed; a stop still wins while paused.
About 60 s (three tests start real processes).
"""

from __future__ import annotations

import asyncio
import math
import subprocess
import sys
import time
from pathlib import Path

import msgspec
import pytest
from conftest import Proc, Robot, free_port, wait_for

from icefloe import config as config_mod
from icefloe.config import Geometry
from icefloe.credentials import make, read
from icefloe.errors import NotReachable
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.sim.clock import SimClock
from icefloe.sim.world import MOTOR_TAU, World

# --------------------------------------------------------------------------- the world itself


def test_place_moves_the_truth_not_the_encoders_and_pause_freezes_the_world() -> None:
    world = World(Geometry(), seed=1)
    clock = SimClock(world)
    world.set_duty(0.5, 0.5)
    clock.run(0.5)
    counts = world.counts()
    assert world.pose[0] > 0.05 and world.wheel_speeds[0] > 0
    world.place(1.0, -2.0, 4.0)  # theta is wrapped
    assert world.pose == pytest.approx((1.0, -2.0, 4.0 - 2 * math.pi))
    assert world.counts() == counts and world.wheel_speeds == (0.0, 0.0)
    clock.paused = True
    clock.run(0.5)  # driven, but frozen
    assert world.pose == pytest.approx((1.0, -2.0, 4.0 - 2 * math.pi)) and world.counts() == counts
    clock.paused = False
    clock.run(0.2)
    assert math.hypot(world.pose[0] - 1.0, world.pose[1] + 2.0) > 0.02
    world.stall("left", True)
    world.set_battery_voltage(6.5)
    world.reset()
    assert world.pose == (0.0, 0.0, 0.0)
    clock.run(0.3)
    assert world.wheel_speeds[0] > 0  # no longer stalled
    assert world.battery_voltage > 7.9  # the pack full again
    for bad in (math.nan, math.inf):
        with pytest.raises(ValueError, match="x must be a finite number"):
            world.place(bad, 0.0, 0.0)
    where = world.pose
    with pytest.raises(ValueError, match="y must be within ±1000 m of the origin, got 1e"):
        world.place(0.0, 1e300, 0.0)
    assert world.pose == where  # a refused place changed nothing


# --------------------------------------------------------------------------- on the bus, from the CLI


def cli(robot: Robot, *args: str, credentials: Path | None = None, robot_name: str | None = None,
        connect: str | None = None, config: Path | None = None) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "icefloe.cli", "sim", *args, "--config", str(config or robot.config_path)]
    if credentials is not None:
        cmd += ["--credentials", str(credentials)]
    if robot_name is not None:
        cmd += ["--robot", robot_name]
    if connect is not None:
        cmd += ["--connect", connect]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=60, env=robot.env)


async def sim_state(node: Node, robot: str | None = None) -> m.SimState:
    return await node.query(keys.SIM_CONTROL, m.SimControl(), timeout=5.0, robot=robot)


async def first_state(node: Node, robot: str | None = None, timeout: float = 60.0) -> m.SimState:
    """The simulator's state once it answers (a busy machine starts it late)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return await sim_state(node, robot)
        except NotReachable:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.3)


async def answers(node: Node, key_expr: str, request: m.Message, timeout: float = 0.5) -> int:
    """How many good answers a query on any key expression (wildcards too) gets."""
    payload = msgspec.msgpack.encode(request)

    def ask() -> int:
        replies = node.session.get(key_expr, payload=payload, encoding="application/msgpack", timeout=timeout)
        return sum(1 for reply in replies if reply.ok is not None)

    return await asyncio.to_thread(ask)


async def test_place_reset_pause_from_the_cli_odometry_carries_on_and_a_stop_wins_while_paused(robot) -> None:
    for service in ("sim", "hwbridge", "odometry"):
        robot.start(service)
    async with robot.node("tester") as node:
        poses = node.subscribe(keys.ODOM_POSE)
        await wait_for(lambda: poses.pending(), timeout=60)
        await first_state(node)
        done = cli(robot, "place", "0.5", "-0.25", "1.5708")
        assert done.returncode == 0, done.stderr
        assert "x 0.500 m, y -0.250 m, theta 1.571 rad" in done.stdout
        state = await sim_state(node)
        assert (state.x, state.y, state.theta) == pytest.approx((0.5, -0.25, 1.5708), abs=1e-4)
        # Odometry counts the wheels: the robot was carried, not driven, so its pose did not jump.
        await anext(poses)
        assert math.hypot((p := await anext(poses)).x, p.y) < 0.01

        # Paused while driving: the truth stays; a stop while paused; nothing moves after resume.
        wheels = node.publisher(keys.WHEELS_CMD)
        for _ in range(5):
            wheels.put(node.command(m.WheelSpeeds, left=0.2, right=0.2))
            await asyncio.sleep(0.1)
        assert cli(robot, "pause").returncode == 0
        paused = await sim_state(node)
        assert paused.paused
        for _ in range(5):
            wheels.put(node.command(m.WheelSpeeds, left=0.2, right=0.2))
            await asyncio.sleep(0.1)
        assert (await sim_state(node)).x == paused.x and (await sim_state(node)).y == paused.y
        node.publisher(keys.STOP).put(node.command(m.Stop))
        await node.query(keys.HALT, node.command(m.Halt, rest=False), timeout=5.0)
        # From the stop on, the board applies no duty (`mark` starts the board model's peak-duty window).
        stopped = await node.query(keys.SIM_CONTROL, m.SimControl(action="mark"), timeout=5.0)
        assert (stopped.duty_left, stopped.duty_right, stopped.peak_duty) == (0.0, 0.0, 0.0), stopped
        assert cli(robot, "resume").returncode == 0
        await asyncio.sleep(1.0)
        after = await sim_state(node)
        assert not after.paused
        assert after.peak_duty == 0.0, f"duty {after.peak_duty} applied after a stop sent while paused"
        # The frozen world kept the speed it had at the pause (on a busy machine the deadman may have
        # stopped the drive before `pause` arrived, leaving the robot rolling out); after the resume it
        # rolls out from that speed, unpowered: v·MOTOR_TAU, and no further.
        rolling = max(abs(paused.speed_left), abs(paused.speed_right))
        assert math.hypot(after.x - paused.x, after.y - paused.y) < 0.002 + rolling * MOTOR_TAU, \
            f"moved after a stop sent while paused (rolling at {rolling:.3f} m/s when paused)"
        assert max(abs(after.speed_left), abs(after.speed_right)) < 1e-3, after

        assert cli(robot, "reset").returncode == 0
        reset = await sim_state(node)
        assert (reset.x, reset.y, reset.theta) == (0.0, 0.0, 0.0)
        # A wildcard robot is refused by the CLI (and a wildcard query by the simulator itself).
        assert cli(robot, "place", "1", "1", "0", robot_name="*").returncode != 0
        place = m.SimControl(action="place", x=1.0, y=1.0, theta=0.0)
        for key_expr in ("icefloe/*/sim/control", "icefloe/**", f"icefloe/{robot.name}/**"):
            assert await answers(node, key_expr, place) == 0, key_expr
        assert (await sim_state(node)).x == 0.0


# --------------------------------------------------------------------------- who may


def lab_config(folder: Path, name: str, endpoint: str, credentials: Path | None) -> Path:
    from conftest import SIM_CONFIG

    run_dir = folder / f"run-{name}"
    run_dir.mkdir(exist_ok=True)
    access = f'access_control = true\ncredentials = "{credentials}"\n' if credentials else ""
    path = folder / f"{name}.toml"
    path.write_text(f'extends = "{SIM_CONFIG}"\nname = "{name}"\nrun_dir = "{run_dir}"\n\n'
                    f'[zenoh]\nlisten = ["{endpoint}"]\nconnect = ["{endpoint}"]\n{access}')
    return path


async def test_only_the_owner_and_the_labs_ta_may_use_the_simulators_handles(make_robot, tmp_path: Path) -> None:
    """A lab router (`icefloe router --lab`) with robot V's and robot O's credentials and a TA's;
    V's simulator logs in as V. Each attacker tries place, reset and pause by the key, by
    wildcards and on another robot's key; the simulator's truth must not move."""
    robot = make_robot()  # for its process handling; its own router is not used
    lab_dir = tmp_path / "lab"
    lab_dir.mkdir(mode=0o700)
    v_creds, _ = make(lab_dir / "v.credentials", "v")
    o_creds, _ = make(lab_dir / "o.credentials", "o")
    ta_path = lab_dir / "ta.credentials"
    make(ta_path, "*")
    ta_path.write_text(ta_path.read_text().replace('user = "*"', 'user = "ta"'))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    lab = lab_config(tmp_path, "lab", endpoint, None)
    router = spawn(robot, "labrouter", [sys.executable, "-m", "icefloe.cli", "router", str(lab), "--lab", str(lab_dir)])
    v_config = lab_config(tmp_path, "v", endpoint, v_creds)
    sim = spawn(robot, "vsim", [sys.executable, "-m", "icefloe.services.sim", "--config", str(v_config)])
    v_cfg = config_mod.load(v_config)
    await wait_for(lambda: "listening" in router.output or not router.alive(), timeout=30)
    assert router.alive(), router.output
    assert "TA account ta" in router.output

    def as_user(user: str, password: str) -> Node:
        zenoh = msgspec.structs.replace(v_cfg.zenoh, user=user, password=password, access_control=False,
                                        credentials="")
        return Node("laptop", msgspec.structs.replace(v_cfg, name="laptop", zenoh=zenoh), retry=False,
                    announce=False)

    v, o, ta = read(v_creds), read(o_creds), read(ta_path)
    async with as_user(v.user, v.password) as owner:
        start = await first_state(owner, "v")
        place = m.SimControl(action="place", x=1.0, y=1.0, theta=0.0)
        attempts = ["icefloe/v/sim/control", "icefloe/*/sim/control", "icefloe/**", "icefloe/v/**",
                    "icefloe/v$*/sim/control", "icefloe/*/sim/*", "**"]
        for user, password in (("guest", "guest"), (o.user, o.password)):
            async with as_user(user, password) as attacker:
                for key in attempts:
                    assert await answers(attacker, key, place) == 0, (user, key)
        # The TA may not reach the simulator through a wildcard, nor do anything else.
        async with as_user(ta.user, ta.password) as ta_node:
            for key in attempts[1:]:
                assert await answers(ta_node, key, place) == 0, ("ta", key)
            for other in ("icefloe/v/odom/reset", "icefloe/v/cmd/motion", "icefloe/v/power/request"):
                assert await answers(ta_node, other, m.SimControl()) == 0, other
            twists = owner.subscribe(keys.TWIST, robot="v")
            pub = ta_node.session.declare_publisher("icefloe/v/cmd/twist")
            await asyncio.sleep(0.3)
            for _ in range(3):
                pub.put(b'{"v": 0.1, "w": 0}')
                await asyncio.sleep(0.05)
            await asyncio.sleep(0.5)
            assert not twists.pending(), "the TA drove the robot"
            pub.undeclare()
        # A wrong password: no session (no login at all is the guest, above).
        for user, password in ((ta.user, "wrong"), (v.user, "wrong"), ("guest", "wrong")):
            with pytest.raises(NotReachable):
                async with as_user(user, password):
                    pass
        # The owner's own wildcard: refused by the router (it reaches other robots).
        assert await answers(owner, "icefloe/*/sim/control", place) == 0
        still = await sim_state(owner, "v")
        assert (still.x, still.y, still.theta) == (start.x, start.y, start.theta), "an attacker moved the robot"

        # The TA, by the robot's name: from the CLI with the TA's credentials file.
        done = cli(robot, "place", "1.5", "-0.5", "0", credentials=ta_path, robot_name="v", connect=endpoint,
                   config=v_config)
        assert done.returncode == 0, done.stdout + done.stderr
        assert (s := await sim_state(owner, "v")).x == pytest.approx(1.5) and s.y == pytest.approx(-0.5)
        done = cli(robot, "place", "1", "1", "0", credentials=ta_path, connect=endpoint, config=v_config)
        assert done.returncode != 0 and "give --robot" in done.stderr
        # The owner too.
        assert (await owner.query(keys.SIM_CONTROL, m.SimControl(action="reset"), timeout=5.0, robot="v")).x == 0.0
    assert sim.alive() and router.alive()



def spawn(robot: Robot, name: str, cmd: list[str]) -> Proc:
    """A process the robot fixture stops at the end of the test."""
    proc = Proc(name, cmd, robot.tmp / f"{name}.log", robot.env)
    robot.procs.append(proc)
    return proc


async def test_the_http_bus_bridge_places_the_robot_for_its_owner_only(make_robot) -> None:
    """``POST /bus/sim/control`` acts under the router's own rules (services/webapi/bus.py)."""
    from test_security import basic
    from webapi_helpers import webapi

    robot = make_robot(f'[webapi]\nhost = "127.0.0.1"\nport = {free_port()}\n', access_control=True)
    robot.start("sim")
    owner = basic(robot.config.zenoh.user, robot.config.zenoh.password)
    place = '{"action": "place", "x": 0.75, "y": 0.25, "theta": 3.0}'
    async with webapi(robot) as http, robot.node("tester") as node:
        start = await first_state(node)

        async def send(path: str, headers: dict[str, str], body: str = place) -> tuple[int, dict]:
            async with http.session.post(http.base + path, data=body, headers=headers) as r:
                return r.status, await r.json()

        refused = [
            ("/bus/sim/control", {}, 401),  # no login: asked for one
            ("/bus/sim/control", basic("guest", "guest"), 403),
            ("/bus/sim/control", basic(robot.config.zenoh.user, "wrong"), 401),
            ("/bus/sim/control", basic("ta", "ta"), 401),  # a user this robot does not know
            ("/bus/icefloe/*/sim/control", owner, 403),  # a wildcard reaching other robots
            ("/bus/icefloe/other/sim/control", owner, 403),
            (f"/bus/icefloe/{robot.name}$*/sim/control", owner, 403),
        ]
        for path, headers, status in refused:
            got, answer = await send(path, headers)
            assert got == status, (path, got, answer)
        still = await sim_state(node)
        assert (still.x, still.y, still.theta) == (start.x, start.y, start.theta), "a refused request moved it"
        status, answer = await send("/bus/sim/control", owner)
        assert status == 200, answer
        [reply] = answer  # Zenoh's REST shape: a list of {key, value, ...}
        assert (reply["value"]["x"], reply["value"]["y"], reply["value"]["theta"]) == pytest.approx((0.75, 0.25, 3.0))
        status, answer = await send("/bus/sim/control", owner, '{"action": "place", "x": "far"}')
        assert status == 400 and "$.x" in answer["message"], answer  # names the field; nothing moved
        assert (await sim_state(node)).x == pytest.approx(0.75)
