"""The web API against the simulated robot: real sim, hwbridge, odometry and webapi processes.

A plain HTTP client drives the robot as pibot_client / PiBot.m would, and the
simulator's ground truth (``sim/truth``) says whether the robot really moved.
"""

from __future__ import annotations

import asyncio
import json
import math

import pytest
from conftest import wait_for
from webapi_helpers import TEXT, K, webapi, webapi_robot

from icefloe.schemas import keys
from icefloe.schemas import messages as m


@pytest.fixture
def robot(make_robot):
    return webapi_robot(make_robot)


async def sim_control(node, **action: object) -> m.SimState:
    return await node.query(keys.SIM_CONTROL, m.SimControl(**action), timeout=5.0)


async def test_drive_the_simulated_robot_over_http(robot):
    for service in ("sim", "hwbridge", "odometry"):
        robot.start(service)
    async with webapi(robot) as http, robot.node("tester") as node:
        truth = node.subscribe(keys.TRUTH)
        await wait_for(lambda: truth.pending(), timeout=20)
        start = await anext(truth)

        async def truth_now() -> m.Truth:
            await anext(truth)  # skip the queued one: the next sample is from after this call
            return await anext(truth)

        # Wait until the robot's services are all up (the state JSON has real numbers).
        async def state() -> dict:
            status, ctype, body = await http.get("/robot/stop")
            assert (status, ctype) == (200, TEXT)
            return json.loads(body)

        for _ in range(200):
            if (await state())["encoder"]["left"] is not None:
                break
            await asyncio.sleep(0.1)

        # A refused request does not move the robot.
        status, _, body = await http.get("/robot/set/velocity", value="50,50", time="1", accel="0.6")
        assert status == 400 and json.loads(body)["message"].startswith("acceleration time too long")
        await asyncio.sleep(0.5)
        assert (await truth_now()).x == pytest.approx(start.x, abs=1e-4)

        # Timed motion, as pibot_client's setVelocity(40, 40, 1.0, 0.2) sends it: blocks until done.
        status, ctype, body = await http.get("/robot/set/velocity", value="40,40", time="1.0",
                                             accel="0.2")
        assert (status, ctype) == (200, TEXT), body
        after = json.loads(body)
        moved = await truth_now()
        left, right = after["encoder"]["left"], after["encoder"]["right"]
        assert left == pytest.approx((moved.x - start.x) / (K / 10), rel=0.1)
        assert abs(left - right) <= 5
        assert after["pose"]["x"] == pytest.approx(moved.x - start.x, abs=0.01)
        # The answer comes when the wheels are told 0; they take a moment to stop, then stay.
        await asyncio.sleep(1.0)
        settled = await truth_now()
        await asyncio.sleep(0.5)
        assert (await truth_now()).x == pytest.approx(settled.x, abs=0.001)
        # The old server's ramp covers V * T (facts §5.3): 40 units = 0.213 m/s, for 1 s.
        assert settled.x - start.x == pytest.approx(40 * K * 1.0, rel=0.2)
        assert abs(settled.y - start.y) < 0.01
        assert await http.get("/robot/get/encoder") == (200, TEXT, await encoder_text(http))

        # Turning counter-clockwise: left wheel back, right forward (PiBot.m's acceleration=).
        status, _, body = await http.get("/robot/set/velocity", value="-20,20", time="1.0",
                                         acceleration="0.1")
        assert status == 200
        await asyncio.sleep(1.0)  # the wheels wind down after the answer; compare once still
        turned = await truth_now()
        theta = (await state())["pose"]["theta"]
        assert turned.theta - start.theta > 0.3  # counter-clockwise in the truth ...
        assert theta == pytest.approx(-(turned.theta - start.theta), abs=0.05)  # ... clockwise here

        # Without time= the speed holds (the deadman does not stop it) until /robot/stop.
        before = await truth_now()
        status, _, _ = await http.get("/robot/set/velocity", value="30.0,30.0")
        assert status == 200
        await asyncio.sleep(1.5)
        assert math.hypot((t := await truth_now()).x - before.x, t.y - before.y) > 0.1
        await http.get("/robot/stop")
        await asyncio.sleep(0.5)
        stopped = await truth_now()
        await asyncio.sleep(0.5)
        assert math.hypot((t := await truth_now()).x - stopped.x, t.y - stopped.y) < 0.002

        # /robot/stop ends a timed motion early; the blocked request then answers.
        motion = asyncio.create_task(http.get("/robot/set/velocity", value="20,20", time="20"))
        await asyncio.sleep(1.0)
        assert not motion.done()
        await http.get("/robot/stop")
        status, _, _ = await asyncio.wait_for(motion, 10)  # long before its 20 s
        assert status == 200
        await asyncio.sleep(1.0)
        stopped = await truth_now()
        await asyncio.sleep(0.5)
        assert math.hypot((t := await truth_now()).x - stopped.x, t.y - stopped.y) < 0.002

        # Resets, as pibot_client's resetEncoder() / resetPose().
        assert await http.get("/robot/hw/reset") == (200, TEXT, "")
        assert await http.get("/robot/get/encoder") == (200, TEXT, "0,0")
        assert await http.get("/robot/pose/reset") == (200, TEXT, "")
        await asyncio.sleep(0.2)
        pose = (await state())["pose"]
        assert abs(pose["x"]) < 1e-3 and abs(pose["y"]) < 1e-3 and abs(pose["theta"]) < 1e-3

        # Battery in mV / mA text, as getVoltage()/getCurrent() parse it.
        status, ctype, body = await http.get("/battery/get/voltage")
        assert (status, ctype) == (200, TEXT) and 6000 < float(body) < 9000
        assert float((await http.get("/battery/get/current"))[2]) >= 0

        # DIP switch and the S4 button, through the simulated HAT.
        await sim_control(node, action="set_dip", dip=5)
        await wait_for_text(http, "/hat/dip/get", "5")
        await http.get("/hat/button/get")  # reset the count
        for _ in range(2):
            await sim_control(node, action="press_button", button=3, seconds=0.1)
            await asyncio.sleep(0.3)
        presses = 0  # each read returns the presses since the last one, and resets the count
        for _ in range(100):
            presses += int((await http.get("/hat/button/get"))[2])
            if presses >= 2:
                break
            await asyncio.sleep(0.1)
        assert presses == 2


async def test_leds_and_screen_reach_hwbridge(robot):
    """The HAT routes as pibot_client sends them; hwbridge takes every message without complaint."""
    hwbridge = robot.start("hwbridge")
    robot.start("sim")
    async with webapi(robot) as http:
        requests = [("/led/set/state", {"id": 2, "value": 1}),
                    ("/led/set/count", {"id": 3, "value": "100.0"}),
                    ("/hat/ledarray/set", {"value": 0x9008}),
                    ("/hat/screen/set", {"value": 2})]
        for path, params in requests:
            assert await http.get(path, **params) == (200, TEXT, ""), path
        assert await http.raw("/hat/screen/print?value=x+=%201%0Adone") == (200, TEXT, "")
        await asyncio.sleep(0.5)
    assert hwbridge.alive()
    assert "dropped" not in hwbridge.output and "rejected" not in hwbridge.output, hwbridge.output


async def encoder_text(http) -> str:
    body = (await http.get("/robot/stop"))[2]
    enc = json.loads(body)["encoder"]
    return f"{enc['left']},{enc['right']}"


async def wait_for_text(http, path: str, expected: str, timeout: float = 10.0) -> None:
    for _ in range(int(timeout / 0.1)):
        status, ctype, body = await http.get(path)
        if body == expected:
            assert (status, ctype) == (200, TEXT)
            return
        await asyncio.sleep(0.1)
    raise AssertionError(f"{path}: {body!r}, expected {expected!r}")
