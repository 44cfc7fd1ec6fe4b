"""The web API process, route by route, against a stand-in robot on the bus (`Board`).

Bodies and content types are compared with the old server's (penguinpi-facts §5.2, §5.5).
"""

from __future__ import annotations

import asyncio
import json
import time

import pytest
from webapi_helpers import TEXT, K, board, wait_for, webapi, webapi_robot

from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.webapi import timing


@pytest.fixture
def robot(make_robot):
    return webapi_robot(make_robot)


async def test_state_routes_read_the_bus_in_the_old_formats(robot):
    async with webapi(robot) as http, board(robot) as b:
        b.ticks = [40000, -70000]  # unwrapped; the firmware's int16 counters would show these wrapped
        b.pose = m.Pose(stamp=0, x=0.5, y=0.25, theta=0.3)  # CCW-positive, y to the left
        b.battery = m.BatteryReading(stamp=0, voltage=7.4125, current=0.3)
        await wait_for_body(http, "/robot/get/encoder", "-25536,-4464")
        await wait_for_body(http, "/battery/get/voltage", "7412.5")
        status, ctype, body = await http.get("/robot/stop")
        assert (status, ctype) == (200, TEXT)
        # json.dumps with default separators, key order as the old server's; old pose
        # convention: y to the right, theta clockwise-positive.
        assert body == ('{"encoder": {"left": -25536, "right": -4464}, '
                        '"pose": {"x": 0.5, "y": -0.25, "theta": -0.3}}')
        assert await http.get("/battery/get/voltage") == (200, TEXT, "7412.5")
        assert await http.get("/battery/get/current") == (200, TEXT, "300.0")
        assert await http.get("/motor/get/encoder", id=0) == (200, TEXT, "-25536")
        assert await http.get("/motor/get/encoder", id=1) == (200, TEXT, "-4464")


async def test_dip_and_buttons(robot):
    async with webapi(robot) as http, board(robot) as b:
        status, _, body = await http.get("/hat/dip/get")
        assert status == 503 and "io/dip" in json.loads(body)["message"]
        dip = b.node.publisher(m_key("io/dip"))
        buttons = b.node.publisher(m_key("io/buttons"))
        dip.put(m.Dip(stamp=0, value=9))
        await wait_for_body(http, "/hat/dip/get", "9")
        for button in (3, 0, 3, 3):  # S4, S1, S4, S4: only S4 counts, as HAT_GET_BUTTON did
            buttons.put(m.Buttons(stamp=0, button=button))
        presses = 0  # each read gives the presses since the last read, and resets the count
        for _ in range(100):
            status, ctype, body = await http.get("/hat/button/get")
            assert (status, ctype) == (200, TEXT)
            presses += int(body)
            if presses >= 3:
                break
            await asyncio.sleep(0.1)
        assert presses == 3
        await asyncio.sleep(0.3)
        assert await http.get("/hat/button/get") == (200, TEXT, "0")  # S1 was not counted


def m_key(name: str) -> keys.Topic:
    return keys.TABLE[name]


async def wait_for_body(http, path: str, expected: str, timeout: float = 10.0) -> None:
    """Poll ``path`` until its body is ``expected`` (the value travels over the bus first)."""
    deadline = time.monotonic() + timeout
    while True:
        status, ctype, body = await http.get(path)
        if body == expected:
            assert (status, ctype) == (200, TEXT)
            return
        assert time.monotonic() < deadline, f"{path}: {body!r}, expected {expected!r}"
        await asyncio.sleep(0.05)


async def test_set_velocity_holds_until_stop(robot):
    async with webapi(robot) as http, board(robot) as b:
        status, ctype, body = await http.get("/robot/set/velocity", value="50,-20")
        assert (status, ctype) == (200, TEXT)
        assert set(json.loads(body)) == {"encoder", "pose"}
        # Re-sent well within the deadman timeout, so the robot keeps going like the old firmware.
        await wait_for(lambda: len(b.wheels) >= 4)
        cmd = b.wheels[-1]
        assert cmd.left == pytest.approx(50 * K) and cmd.right == pytest.approx(-20 * K)
        assert cmd.left == pytest.approx(0.2611, abs=1e-4)  # about 5.22 mm/s per unit (sim.toml's 63.82 mm wheels)
        # pibot_client sends floats as "50.0"; the old server refused them, we take them.
        status, _, _ = await http.get("/robot/set/velocity", value="30.0,30.0")
        assert status == 200
        await wait_for(lambda: b.wheels[-1].left == pytest.approx(30 * K))
        # Demand 100 (0.53 m/s) is beyond max_wheel_speed: hwbridge clamps it, as the old board did;
        # the Python client would refuse it, the web API passes it on.
        status, _, _ = await http.get("/robot/set/velocity", value="100,-100")
        assert status == 200
        await wait_for(lambda: b.wheels[-1].left == pytest.approx(100 * K))
        await http.get("/robot/stop")
        await wait_for(lambda: len(b.stops) == 1)
        count = len(b.wheels)
        await asyncio.sleep(0.5)  # four resend periods: nothing more may come
        assert len(b.wheels) == count


async def test_single_motor_velocity(robot):
    async with webapi(robot) as http, board(robot) as b:
        assert await http.get("/motor/set/velocity", id=0, value=40) == (200, TEXT, "")
        await wait_for(lambda: b.wheels and b.wheels[-1].left == pytest.approx(40 * K))
        assert b.wheels[-1].right == 0
        await http.get("/motor/set/velocity", id=1, value=-10)
        await wait_for(lambda: b.wheels[-1].right == pytest.approx(-10 * K))
        assert b.wheels[-1].left == pytest.approx(40 * K)
        await http.get("/robot/stop")


async def test_timed_motion_blocks_until_the_robot_has_stopped(robot):
    async with webapi(robot) as http, board(robot) as b:
        status, ctype, body = await http.get("/robot/set/velocity", value="20,20", time="0.6",
                                             accel="0.2")
        answered = time.monotonic()
        assert (status, ctype) == (200, TEXT), body
        (motion,) = b.motions
        # held for T' (the run-on taken off: services/webapi/timing.py), ramped as asked
        held = timing.timed_duration(20, 20, 0.6, 0.2, unit=K, max_speed=0.5, max_accel=2.0)
        assert held < 0.6
        assert (motion.left, motion.right, motion.duration, motion.accel) == (
            pytest.approx(20 * K), pytest.approx(20 * K), pytest.approx(held), 0.2)
        assert motion.sender and motion.seq > 0  # numbered and stamped, as every command
        assert b.motion_done_at and b.motion_done_at[0] <= answered  # the reply came after the end
        assert json.loads(body)["encoder"] == {"left": 0, "right": 0}
        # PiBot.m spells it acceleration=; the old server ignored it, we take it as accel=.
        status, _, _ = await http.get("/robot/set/velocity", value="10,-10", time="0.3",
                                      acceleration="0.1")
        assert status == 200
        assert b.motions[-1].accel == 0.1
        assert b.motions[-1].duration == pytest.approx(
            timing.timed_duration(10, -10, 0.3, 0.1, unit=K, max_speed=0.5, max_accel=2.0))


async def test_resets(robot):
    async with webapi(robot) as http, board(robot) as b:
        b.ticks = [1000, 2000]
        b.pose = m.Pose(stamp=0, x=1.0, y=2.0, theta=1.0)
        await wait_for_body(http, "/robot/get/encoder", "1000,2000")
        assert await http.get("/robot/hw/reset") == (200, TEXT, "")
        await wait_for(lambda: len(b.stops) == 1)
        assert await http.get("/robot/get/encoder") == (200, TEXT, "0,0")
        b.ticks = [1010, 1990]
        await wait_for_body(http, "/robot/get/encoder", "10,-10")
        assert await http.get("/robot/pose/reset") == (200, TEXT, "")
        assert b.resets == [m.PoseReset()]
        await asyncio.sleep(0.2)
        pose = json.loads((await http.get("/robot/stop"))[2])["pose"]
        assert pose == {"x": 0.0, "y": -0.0, "theta": -0.0}


async def test_leds_screen_and_text(robot):
    async with webapi(robot) as http, board(robot) as b:
        seen: list[object] = []

        async def record(name: str) -> None:
            async for msg in b.node.subscribe(m_key(name), latest=False):
                seen.append(msg)

        tasks = [asyncio.create_task(record(n)) for n in ("io/leds", "io/ledarray", "io/text",
                                                           "io/screen")]
        await asyncio.sleep(0.3)
        assert await http.get("/led/set/state", id=2, value=1) == (200, TEXT, "")
        assert await http.get("/led/set/count", id="0x3", value="100.0") == (200, TEXT, "")
        assert await http.get("/hat/ledarray/set", value="0b1010") == (200, TEXT, "")
        assert await http.get("/hat/screen/set", value=4) == (200, TEXT, "")
        # pibot_client does not URL-encode: '+' arrives as a space, %0A as a new line.
        assert await http.raw("/hat/screen/print?value=x+=%201%0Adone") == (200, TEXT, "")
        expected = [m.Led(led=2, on=True), m.Led(led=3, on=True, pulse=0.1),
                    m.LedArray(mask=10), m.OledScreen(index=4),
                    m.OledText(text="x = 1\ndone"), m.OledScreen(index=1)]
        await wait_for(lambda: len(seen) >= len(expected))
        await asyncio.sleep(0.1)
        for t in tasks:
            t.cancel()
        assert sorted(map(repr, seen)) == sorted(map(repr, expected))


BAD = [
    # (path, params, message start)
    ("/robot/set/velocity", {}, "invalid speeds: missing value="),
    ("/robot/set/velocity", {"value": "50"}, "invalid speeds: value='50': expected two numbers"),
    ("/robot/set/velocity", {"value": "fast,slow"}, "invalid speeds: value='fast,slow': 'fast' is not"),
    ("/robot/set/velocity", {"value": "nan,1"}, "invalid speeds: value='nan,1': 'nan' is not"),
    ("/robot/set/velocity", {"value": "1e999,1"}, "invalid speeds: value='1e999,1': '1e999' is too"),
    ("/robot/set/velocity", {"value": "50,101"}, "invalid speeds: right speed 101 is outside -100..100"),
    ("/robot/set/velocity", {"value": "50,50", "time": "soon"}, "bad time given: time: 'soon'"),
    ("/robot/set/velocity", {"value": "50,50", "time": "-1"}, "bad time given: time=-1 must be > 0"),
    ("/robot/set/velocity", {"value": "50,50", "time": "0"}, "bad time given: time=0 must be > 0"),
    ("/robot/set/velocity", {"value": "50,50", "time": "1e6"}, "bad time given: time=1e+06 is longer"),
    ("/robot/set/velocity", {"value": "50,50", "time": "1", "accel": "x"},
     "bad acceleration given: accel: 'x'"),
    ("/robot/set/velocity", {"value": "50,50", "time": "1", "accel": "-0.1"},
     "bad acceleration given: accel=-0.1 must be >= 0"),
    ("/robot/set/velocity", {"value": "50,50", "time": "1", "accel": "0.5"},
     "acceleration time too long: time=1 must be more than 2 x accel=0.5"),
    ("/robot/set/velocity", {"value": "50,50", "time": "1", "accel": "0.1", "acceleration": "0.1"},
     "bad acceleration given: give accel= or acceleration=, not both"),
    ("/robot/set/velocity", {"value": "50,50", "accel": "0.1"}, "bad acceleration given: accel= needs"),
    ("/motor/set/velocity", {"id": "2", "value": "10"}, "Bad motor id: id=2 is outside 0..1"),
    ("/motor/set/velocity", {"id": "0", "value": "1000"}, "Bad motor value: value=1000 is outside"),
    ("/motor/set/velocity", {"id": "0"}, "Bad motor value: missing value="),
    ("/motor/get/encoder", {"id": "x"}, "Bad motor id: id='x' is not an integer"),
    ("/hat/ledarray/set", {"value": "0x10000"}, "Bad value: value=65536 is outside 0..65535"),
    ("/hat/ledarray/set", {"value": "lots"}, "Bad value: value='lots' is not an integer"),
    ("/hat/ledarray/set", {}, "Bad value: missing value="),
    ("/hat/screen/set", {"value": "256"}, "Bad screen value: value=256 is outside 0..255"),
    ("/hat/screen/set", {"value": "-1"}, "Bad screen value: value=-1 is outside 0..255"),
    ("/hat/screen/set", {"value": "one"}, "Bad screen value: value='one' is not an integer"),
    ("/hat/screen/print", {}, "Bad text: missing value="),
    ("/hat/screen/print", {"value": "x" * 1001}, "Bad text: 1001 characters, at most 1000"),
    ("/led/set/state", {"id": "5", "value": "1"}, "Bad led id: id=5 is outside 2..4"),
    ("/led/set/state", {"id": "2", "value": "2"}, "Bad led value: value=2 is outside 0..1"),
    ("/led/set/state", {"value": "1"}, "Bad led id: missing id="),
    ("/led/set/count", {"id": "2", "value": "300"}, "Bad led value: value=300 is outside 0..255"),
    ("/led/set/count", {"id": "2", "value": "-5"}, "Bad led value: value=-5 is outside 0..255"),
    ("/led/set/count", {"id": "2", "value": "1.5"}, "Bad led value: value='1.5' is not a whole"),
]


async def test_bad_input_is_refused_and_nothing_moves(robot):
    async with webapi(robot) as http, board(robot) as b:
        await asyncio.sleep(0.3)  # the recorder is subscribed
        for path, params, message in BAD:
            status, ctype, body = await http.get(path, **params)
            assert (status, ctype) == (400, "application/json"), (path, params, body)
            assert json.loads(body)["message"].startswith(message), (path, params, body)
        # A request after the bad ones, so we know the bus delivered everything before it.
        await http.get("/hat/screen/set", value=2)
        await wait_for(lambda: "io/screen" in b.raw)
        assert b.raw == ["io/screen"], "a refused request sent something to the robot"
        assert b.motions == []


async def test_routes_without_a_robot_say_which_service_is_missing(robot):
    async with webapi(robot) as http:
        for path in ("/robot/get/encoder", "/battery/get/voltage", "/hat/dip/get"):
            status, ctype, body = await http.get(path)
            assert (status, ctype) == (503, "application/json"), (path, body)
            assert f"icefloe/{robot.name}/" in json.loads(body)["message"]
        status, _, body = await http.get("/robot/set/velocity", value="10,10", time="0.2")
        assert status == 503 and "cmd/motion" in json.loads(body)["message"]
        # A stop nobody confirms is not reported as done.
        status, _, body = await http.get("/robot/stop")
        assert status == 503 and "cmd/halt" in json.loads(body)["message"]
        # The state JSON still answers, with the old server's placeholders.
        assert (await http.get("/robot/set/velocity", value="0,0"))[2] == (
            '{"encoder": {"left": null, "right": null}, "pose": {"x": 0, "y": 0, "theta": 0}}')


async def test_an_answer_refused_or_unreadable_is_a_502_naming_the_key(robot):
    """Whatever answers odom/reset or cmd/motion (on a robot without access control, anyone
    may) can reply garbage or an error: the caller gets a 502 naming the key, not a 500."""
    async with webapi(robot) as http, robot.node("impostor") as node:
        garbled = node.session.declare_queryable(node.key(keys.ODOM_RESET),
                                                 lambda q: q.reply(q.key_expr, b"\x93garbage"))
        refusing = node.session.declare_queryable(node.key(keys.MOTION), lambda q: q.reply_err(b"busy"))
        deadline = time.monotonic() + 15
        while (answer := await http.get("/robot/pose/reset"))[0] == 503:  # until the impostor reaches the router
            assert time.monotonic() < deadline, answer
            await asyncio.sleep(0.1)
        status, ctype, body = answer
        assert (status, ctype) == (502, "application/json"), body
        assert f"icefloe/{robot.name}/odom/reset" in json.loads(body)["message"]
        status, _, body = await http.get("/robot/set/velocity", value="10,10", time="0.2")
        assert status == 502 and json.loads(body)["message"].endswith(f"icefloe/{robot.name}/cmd/motion: busy")
        assert "Traceback" not in http.proc.output and http.proc.alive()
        assert await http.get("/hat/button/get") == (200, TEXT, "0")
        garbled.undeclare()
        refusing.undeclare()


async def test_bad_bus_payloads_are_dropped_and_the_service_goes_on(robot):
    async with webapi(robot) as http, robot.node("tester") as node:
        # The web API follows the state while routes read it: read first (nothing yet), then
        # the bad samples come; each is dropped when read (io/buttons: as it comes).
        async def read_all() -> None:
            assert (await http.get("/robot/get/encoder"))[0] == 503
            assert (await http.get("/hat/dip/get"))[0] == 503
            assert (await http.get("/robot/set/velocity", value="0,0"))[0] == 200  # odom/pose too

        await read_all()
        bad = {"io/dip": (b'{"value": "nine"}', "Expected `int`, got `str`"),
               "io/buttons": (b'{"button": 3, "x": 1}', "Object contains unknown field `x`"),
               "hw/wheels": (b"{not json", "not valid JSON"),
               "odom/pose": (b'{"stamp": 0}', "Object missing required field `x`")}

        def missing() -> list[str]:
            """The keys whose "dropped" line has not shown yet (one line each, not a count of
            lines: io/buttons has two subscribers in webapi, each drops it with a line)."""
            return [key for key, (_, line) in bad.items()
                    if f"dropped: icefloe/{robot.name}/{key}: {line}" not in http.proc.output]

        # The log shows a few lines a second (the 503s' lines count too): a line over the limit
        # is only counted, so a key whose line has not shown is sent again, and read again.
        deadline = time.monotonic() + 30
        while keys_left := missing():
            assert time.monotonic() < deadline, (keys_left, http.proc.output)
            for key in keys_left:
                node.session.put(node.key(key), bad[key][0], encoding="application/json")
            await asyncio.sleep(0.5)
            await read_all()
        # Nothing of it was taken: no counts, no DIP, no presses, and the service answers.
        assert (await http.get("/robot/get/encoder"))[0] == 503
        assert (await http.get("/hat/dip/get"))[0] == 503
        assert await http.get("/hat/button/get") == (200, TEXT, "0")
        assert http.proc.alive()
