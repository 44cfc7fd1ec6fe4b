"""Over HTTP: the robot's owner cannot forge the robot's external pose through the web API's bus
bridge (services/webapi/bus.py), which asks the router's own rules; anyone may read it. A real
webapi process on a robot with access control (~10 s)."""

from __future__ import annotations

import asyncio

from conftest import free_port
from test_security import basic
from webapi_helpers import webapi

from icefloe.router import access_control, permits
from icefloe.schemas import keys


def test_overhead_pose_rules_only_the_lab_localizer_may_put() -> None:
    acl = access_control([("r1", "r1"), ("lab", "lab")], localizers=["lab"])
    for key in ("icefloe/r1/extloc/pose", "icefloe/r2/extloc/pose", "icefloe/*/extloc/pose", "icefloe/r1/extloc/**"):
        assert not permits(acl, "r1", "put", key), key  # the owner: not even their own robot's
        assert not permits(acl, "r1", "delete", key), key
        assert not permits(acl, "guest", "put", key), key
    assert permits(acl, "lab", "put", "icefloe/r1/extloc/pose")
    assert permits(acl, "lab", "put", "icefloe/r2/extloc/pose")
    assert not permits(acl, "lab", "put", "icefloe/r1/cmd/twist")  # the localizer commands nobody
    assert permits(acl, "guest", "declare_subscriber", "icefloe/r1/extloc/pose")
    assert permits(acl, "r1", "put", "icefloe/r1/cmd/twist")  # the owner still drives


async def test_overhead_pose_cannot_be_forged_over_http(make_robot) -> None:
    robot = make_robot(f'[webapi]\nhost = "127.0.0.1"\nport = {free_port()}\n', access_control=True)
    owner = basic(robot.config.zenoh.user, robot.config.zenoh.password)
    fake = '{"stamp": 1, "x": 9.5, "y": 0, "theta": 0, "covariance": [0,0,0,0,0,0,0,0,0]}'
    async with webapi(robot) as http, robot.node("tester") as node:
        heard = node.subscribe(keys.EXTLOC_POSE, latest=False)
        await asyncio.sleep(0.5)

        async def put(path: str, headers: dict[str, str]) -> tuple[int, dict]:
            async with http.session.put(http.base + path, data=fake, headers=headers) as r:
                return r.status, await r.json()

        for path in ("/bus/extloc/pose", f"/bus/icefloe/{robot.name}/extloc/pose", "/bus/icefloe/other/extloc/pose"):
            status, answer = await put(path, owner)
            assert status == 403 and "extloc/pose" in answer["message"], (path, answer)
            status, answer = await put(path, {})
            assert status == 401, (path, answer)
        status, answer = await put("/bus/icefloe/*/extloc/pose", owner)
        assert status == 400, answer  # a wildcard is no key to publish on
        await asyncio.sleep(0.5)
        assert heard.pending() == 0, "a refused pose reached the bus"
        # Anyone may read it (the guest, without a login): nothing published here, so "nothing
        # published" (503), not a refusal. (On this robot's own router only its lab link brings poses:
        # tests/test_extloc_overhead_lab.py.)
        status, _, body = await http.get("/bus/extloc/pose")
        assert status == 503 and "nothing published" in body, body
