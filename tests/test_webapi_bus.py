"""The bus over HTTP (services/webapi/bus.py): GET, POST, PUT and Server-Sent Events against a
real webapi process and a stand-in robot on the bus (`Board`), as a curl user, a browser or
MATLAB would use them."""

from __future__ import annotations

import asyncio
import socket
import time
from pathlib import Path
from typing import Any

import aiohttp
import numpy as np
import pytest
from conftest import free_port, wait_for
from webapi_helpers import board, sse_events, webapi, webapi_robot

from icefloe.schemas import keys
from icefloe.schemas import messages as m


@pytest.fixture
def robot(make_robot):
    return webapi_robot(make_robot)


async def test_get_the_latest_sample_and_ask_queryables(robot):
    async with webapi(robot) as http, board(robot) as b:
        b.pose = m.Pose(stamp=0, x=0.5, y=0.25, theta=0.3)
        status, answer = await http.send("GET", "/bus/odom/pose")
        assert status == 200, answer
        [sample] = answer  # Zenoh's REST shape: a list of {key, value, encoding, time}
        assert sample["key"] == f"icefloe/{robot.name}/odom/pose"
        assert (sample["value"]["x"], sample["value"]["theta"]) == (0.5, 0.3)
        assert sample["encoding"] == "application/json" and sample["time"].endswith(
            sample["time"].rsplit("/", 1)[-1]) and "T" in sample["time"]
        status, value = await http.send("GET", f"/bus/icefloe/{robot.name}/odom/pose", _raw="")
        assert status == 200 and value["y"] == 0.25  # ?_raw: the message alone; a full key works too
        # A queryable: the request from the URL's parameters (MATLAB's webread(url, "x", 1)) ...
        status, [reply] = await http.send("GET", "/bus/odom/reset", x="1.5", theta="0.1")
        assert status == 200 and reply["value"]["x"] == 1.5
        assert b.resets[-1] == m.PoseReset(x=1.5, y=0.0, theta=0.1)
        # ... or from a JSON body, POSTed as a browser must.
        status, [reply] = await http.send("POST", "/bus/odom/reset", '{"y": -2}')
        assert status == 200 and b.resets[-1] == m.PoseReset(y=-2.0)
        status, answer = await http.send("POST", "/bus/odom/reset", '{"y": "far"}')
        assert status == 400 and "Expected `float`, got `str` - at `$.y`" in answer["message"]
        # Nobody answers info here (no info service): 503 naming the key.
        status, answer = await http.send("GET", "/bus/info")
        assert status == 503 and f"icefloe/{robot.name}/info: nobody answers" in answer["message"]


async def test_put_publishes_checked_json_and_refuses_the_rest(robot):
    async with webapi(robot) as http, robot.node("tester") as node:
        twists = node.subscribe(keys.TWIST)
        stops = node.subscribe(keys.STOP)
        await asyncio.sleep(0.5)
        status, sent = await http.send("PUT", "/bus/cmd/twist", '{"v": 0.1, "w": -0.2}')
        assert status == 200 and sent["key"] == f"icefloe/{robot.name}/cmd/twist"
        twist = await asyncio.wait_for(anext(twists), 5)
        assert (twist.v, twist.w) == (0.1, -0.2)
        # Numbered as the web API's own commands, so a stop sent after it wins (docs/hwbridge.md).
        assert twist.sender and twist.seq > 0 and twist.stamp > 0
        assert (await http.send("PUT", "/bus/cmd/stop", ""))[0] == 200  # an empty body is an empty map
        await asyncio.wait_for(anext(stops), 5)
        refused = [
            ('{"v": "fast", "w": 0}', "Expected `float`, got `str` - at `$.v`"),
            ('{"v": 0.1}', "Object missing required field `w`"),
            ('{"v": 0.1, "w": 0, "turbo": true}', "unknown field `turbo`"),
            ('{"v": 1e999, "w": 0}', "$.v"),
            ("v=0.1&w=0", "not valid JSON"),
            ("[0.1, 0]", "Expected `object`, got `array`"),
        ]
        for body, message in refused:
            status, answer = await http.send("PUT", "/bus/cmd/twist", body)
            assert status == 400, (body, answer)
            assert answer["message"].startswith(f"icefloe/{robot.name}/cmd/twist: ") and message in answer["message"]
        assert (await http.send("PUT", "/bus/cmd/twist", "x" * (2 << 20)))[0] == 413
        await asyncio.sleep(0.5)
        assert twists.pending() == 0, "a refused PUT published something"


async def test_unknown_keys_are_404_and_wrong_methods_say_what_to_do(robot):
    async with webapi(robot) as http:
        for path in ("/bus/nosuch", "/bus/odom/posture", f"/bus/icefloe/{robot.name}/cmd/twist/x",
                     "/bus/elsewhere/**", "/bus/@/router/local"):
            status, answer = await http.send("GET", path)
            assert status == 404, (path, answer)
            assert "key table" in answer["message"], answer
        assert (await http.send("PUT", "/bus/nosuch", "{}"))[0] == 404
        status, answer = await http.send("PUT", "/bus/cmd/*", '{"v": 0, "w": 0}')
        assert status == 400 and "not a wildcard" in answer["message"]
        status, answer = await http.send("PUT", "/bus/info", "{}")
        assert status == 405 and "queryable" in answer["message"]
        status, answer = await http.send("GET", "/bus/hw/*")  # topics are followed, not asked
        assert status == 400 and "text/event-stream" in answer["message"]
        assert (await http.send("DELETE", "/bus/odom/pose"))[0] == 405
        status, answer = await http.send("GET", "/bus/odom/pose")  # nothing published: 503, soon
        assert status == 503 and "nothing published" in answer["message"]


async def test_server_sent_events_follow_keys_wildcards_and_services(robot):
    async with webapi(robot) as http, board(robot) as b:
        b.battery = m.BatteryReading(stamp=0, voltage=7.4, current=0.3)
        events = await http.events("/bus/odom/pose", 5)
        assert {name for name, _ in events} == {"PUT"}
        assert all(data["key"] == f"icefloe/{robot.name}/odom/pose" for _, data in events)
        # A wildcard, at most 2 samples a second of each key: the newest of each.
        start = time.monotonic()
        events = await http.events(f"/bus/icefloe/{robot.name}/hw/*", 6, _rate="2")
        keys_seen = [data["key"].rsplit("/", 1)[-1] for _, data in events]
        assert set(keys_seen) == {"wheels", "battery"}
        assert time.monotonic() - start > 1.0, "more than 2 a second per key"
        # Services come and go as liveliness tokens: PUT when one starts, DELETE when it stops.
        got: list[tuple[str, str]] = []

        async def follow() -> None:
            async with http.session.get(http.base + "/bus/alive/*", headers={"Accept": "text/event-stream"}) as r:
                async for name, data in sse_events(r.content):
                    got.append((name, data["key"].rsplit("/", 1)[-1]))

        task = asyncio.create_task(follow())
        await wait_for(lambda: ("PUT", "board") in got)  # the ones alive now come first
        async with robot.node("newcomer"):
            await wait_for(lambda: ("PUT", "newcomer") in got)
        await wait_for(lambda: ("DELETE", "newcomer") in got)
        task.cancel()
        status, tokens = await http.send("GET", "/bus/alive/*")
        assert status == 200
        assert {t["key"].rsplit("/", 1)[-1] for t in tokens} >= {"board", "webapi"}


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def noisy_jpeg(seed: int) -> bytes:
    """A camera frame that compresses badly (~100 kB): what fills queues fastest."""
    import cv2

    image = np.random.default_rng(seed).integers(0, 255, (240, 320, 3), dtype=np.uint8)
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return data.tobytes()


def stalled_client(port: int, path: str) -> socket.socket:
    """A client that asks for a stream and never reads a byte (its receive buffer kept small)."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", port))
    sock.sendall(f"GET {path} HTTP/1.1\r\nHost: x\r\nAccept: text/event-stream\r\n\r\n".encode())
    return sock


async def publish_frames(node, frame: bytes, rate: float = 5.0) -> None:
    images = node.publisher(keys.IMAGE)
    while True:
        images.put(m.Image(stamp=time.time_ns(), width=320, height=240, data=frame))
        await asyncio.sleep(1 / rate)


@pytest.mark.slow
async def test_a_hundred_streams_at_once_in_bounded_memory(robot):
    """100 clients on everything the robot publishes, camera frames of ~100 kB among it: half of
    them read, half never do. The readers get their samples, the webapi's memory stays bounded,
    and it still answers at once."""
    async with webapi(robot) as http, board(robot) as b:
        frames = asyncio.create_task(publish_frames(b.node, noisy_jpeg(1)))
        await http.events("/bus/camera/image", 1)
        pid = http.proc.popen.pid
        before = rss_mb(pid)
        path = f"/bus/icefloe/{robot.name}/**"
        counts = [0] * 50

        async def reader(i: int) -> None:
            async with aiohttp.ClientSession() as session, session.get(
                    http.base + path, headers={"Accept": "text/event-stream"}) as r:
                async for _ in sse_events(r.content):
                    counts[i] += 1

        stalled = [stalled_client(robot.config.webapi.port, path) for _ in range(50)]
        tasks = [asyncio.create_task(reader(i)) for i in range(50)]
        peak = before
        for _ in range(16):  # 8 s: long enough for every stalled client's queue to fill
            await asyncio.sleep(0.5)
            peak = max(peak, rss_mb(pid))
        answered = time.monotonic()
        status, _ = await http.send("GET", "/bus/odom/pose")
        answered = time.monotonic() - answered
        for t in [*tasks, frames]:
            t.cancel()
        for sock in stalled:
            sock.close()
        print(f"webapi RSS {before:.0f} -> peak {peak:.0f} MB; GET answered in {answered * 1000:.0f} ms; "
              f"samples per reader {min(counts)}..{max(counts)}")
        assert status == 200 and answered < 2.0, answered
        assert min(counts) > 20, counts  # every reader got a stream
        # Each stalled client holds at most its queue (256 kB) and what one write buffers.
        assert peak - before < 100, f"RSS grew {peak - before:.0f} MB ({before:.0f} -> {peak:.0f} MB)"
        assert http.proc.alive()


async def test_access_control_is_zenohs_own(make_robot):
    """On a robot with access control the bridge lets a request do what Zenoh lets its user do:
    the guest (no login, or guest:guest) watches and asks read-only queryables; only the owner
    publishes and commands, on this robot's own keys only; a wrong login is 401. What a refused
    request would have sent is checked on the bus, through the robot's own router."""
    from test_security import basic

    robot = make_robot(f'[webapi]\nhost = "127.0.0.1"\nport = {free_port()}\n', access_control=True)
    user, password = robot.config.zenoh.user, robot.config.zenoh.password
    owner, guest = basic(user, password), basic("guest", "guest")
    twist = '{"v": 0.1, "w": 0}'
    async with webapi(robot) as http, robot.node("tester") as node:
        twists = node.subscribe(keys.TWIST)
        await asyncio.sleep(0.5)

        async def send(method: str, path: str, headers: dict[str, str], body: str = "") -> tuple[int, str, Any]:
            async with http.session.request(method, http.base + path, data=body, headers=headers) as r:
                return r.status, r.headers.get("WWW-Authenticate", ""), await r.json()

        # No login: the guest. A write asks for the owner's login (the challenge MATLAB waits for).
        status, challenge, answer = await send("PUT", "/bus/cmd/twist", {}, twist)
        assert status == 401 and challenge.startswith("Basic realm="), answer
        # The guest's own login: 403 naming the key and the user.
        for method, path in (("PUT", "/bus/cmd/twist"), ("PUT", "/bus/cmd/stop"), ("POST", "/bus/odom/reset")):
            status, _, answer = await send(method, path, guest, twist if "twist" in path else "{}")
            assert status == 403 and "user 'guest' may not" in answer["message"], (path, answer)
        # A wrong password, another user: 401, nothing done.
        for wrong in (basic(user, "x"), basic("nobody", password), {"Authorization": "Basic !!"}):
            status, _, answer = await send("PUT", "/bus/cmd/twist", wrong, twist)
            assert status == 401, (wrong, answer)
        # The owner, on another robot's keys or through a wildcard: refused as Zenoh refuses it.
        status, _, answer = await send("PUT", "/bus/icefloe/other/cmd/twist", owner, twist)
        assert status == 403 and "icefloe/other/cmd/twist" in answer["message"], answer
        status, _, answer = await send("POST", "/bus/icefloe/*/odom/reset", owner, "{}")
        assert status == 403, answer
        await asyncio.sleep(0.5)
        assert twists.pending() == 0, "a refused request reached the bus"
        # The guest watches: a stream through its own guest session hears the owner's PUT.
        async with http.session.get(http.base + "/bus/cmd/twist",
                                    headers={"Accept": "text/event-stream"}) as stream:
            assert stream.status == 200
            await asyncio.sleep(0.5)  # its subscriber reaches the router
            status, _, answer = await send("PUT", "/bus/cmd/twist", owner, twist)
            assert status == 200, answer
            name, data = await asyncio.wait_for(anext(sse_events(stream.content)), 10)
            assert name == "PUT" and data["value"]["v"] == 0.1
        assert (await asyncio.wait_for(anext(twists), 5)).v == 0.1
        # The guest lists the services (liveliness) as a guest may over Zenoh.
        status, _, answer = await send("GET", "/bus/alive/*", guest)
        assert status == 200 and any(s["key"].endswith("/alive/webapi") for s in answer), answer
        # The robot's page is anyone's to load; its old forms change the robot: the owner's.
        assert (await http.get("/"))[0] == 200
        for path in ("/speed", "/settings", "/"):
            async with http.session.post(http.base + path, data={"STOP": "STOP"}) as r:
                assert r.status == 401, path


@pytest.mark.parametrize(("message", "key_expr", "guest", "owner"), [
    ("declare_subscriber", "icefloe/r1/cmd/twist", True, True),
    ("declare_subscriber", "icefloe/**", True, True),
    ("put", "icefloe/r1/cmd/twist", False, True),
    ("put", "icefloe/*/cmd/twist", False, False),  # a wildcard reaching other robots
    ("put", "icefloe/r1$*/cmd/twist", False, False),
    ("put", "icefloe/r2/cmd/twist", False, False),
    ("query", "icefloe/r1/info", True, True),  # a read-only queryable
    ("query", "icefloe/r1/odom/reset", False, True),
    ("liveliness_query", "icefloe/r1/alive/*", True, True),
])
def test_the_bridge_decides_as_the_router(message, key_expr, guest, owner):
    """`permits` reads the very rules the router gets (deploy/zenoh/acl/, `access_control`)."""
    from icefloe.router import access_control, permits

    acl = access_control([("r1", "r1")], lab_protocols=["ws"])
    assert (permits(acl, "guest", message, key_expr), permits(acl, "r1", message, key_expr)) == (guest, owner)
