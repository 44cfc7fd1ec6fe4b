"""The web API at rest: no subscription to the robot's state until an HTTP client reads it.

The webapi process against a stand-in robot (`Board`, in this process), its subscriptions
as the robot's router reports them (Zenoh's admin space, `icefloe.graph`); the idle drop of
`services.webapi.state` in-process with a short idle time, on the same real router.
About 40 s on a busy 2-core machine.
"""

from __future__ import annotations

import asyncio
import time

import pytest
from webapi_helpers import TEXT, board, webapi, webapi_robot

from icefloe import graph
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.webapi.fanout import MAX_CHANNELS
from icefloe.services.webapi.state import FOLLOWED, State

STATE_KEYS = [t.name for t in FOLLOWED]  # hw/wheels, odom/pose, hw/battery, io/dip


@pytest.fixture
def robot(make_robot):
    return webapi_robot(make_robot)


async def webapi_subscriptions(node: Node) -> list[str]:
    """The key expressions the webapi process subscribes to now, as the router reports them."""
    found = await graph.read(node.session)
    names = found.names()
    zids = [z for z, name in names.items() if name == f"{node.robot}/webapi"]
    assert zids, f"no webapi session in the router's admin space: {names}"
    return sorted(d.key_expr for z in zids for d in found.by_session[z] if d.kind == "subscriber")


def state_subscriptions(subs: list[str], robot: str) -> set[str]:
    return {s.removeprefix(f"icefloe/{robot}/") for s in subs} & set(STATE_KEYS)


async def test_no_state_followed_until_a_route_reads_it_and_the_first_read_is_right(robot):
    async with webapi(robot) as http, board(robot) as b:
        b.ticks = [1234, -567]
        b.battery = m.BatteryReading(stamp=0, voltage=7.5, current=0.25)
        await asyncio.sleep(1.0)  # the board publishes at 20 Hz all along
        assert state_subscriptions(await webapi_subscriptions(b.node), robot.name) == set()
        # The first read after rest subscribes and answers with the newest counts, not a 503.
        t0 = time.monotonic()
        assert await http.get("/robot/get/encoder") == (200, TEXT, "1234,-567")
        first = time.monotonic() - t0
        assert await http.get("/battery/get/voltage") == (200, TEXT, "7500.0")
        # Followed now: the next reads are answered from the newest sample, without a wait.
        b.ticks = [1300, -600]
        deadline = time.monotonic() + 10
        while (await http.get("/robot/get/encoder"))[2] != "1300,-600":
            assert time.monotonic() < deadline
        t0 = time.monotonic()
        for _ in range(20):
            assert (await http.get("/motor/get/encoder", id=0))[2] == "1300"
        polled = (time.monotonic() - t0) / 20
        assert state_subscriptions(await webapi_subscriptions(b.node), robot.name) == {"hw/wheels", "hw/battery"}
        print(f"first read after rest {first * 1000:.0f} ms; then {polled * 1000:.1f} ms a read")
        assert first < 1.5  # ~20 ms on a quiet machine (the board sends at 20 Hz): a bounded wait


async def test_a_client_polling_hundreds_of_routes_and_keys_does_not_grow_subscriptions(robot):
    async with webapi(robot) as http, board(robot) as b:
        await asyncio.sleep(0.5)
        before = await webapi_subscriptions(b.node)
        routes = ["/robot/get/encoder", "/motor/get/encoder?id=1", "/battery/get/voltage", "/hat/dip/get",
                  "/robot/set/velocity?value=0,0", "/hat/button/get"]
        # Hundreds of reads of the old routes, and of the HTTP bridge's keys, many at once.
        reads = [http.raw(routes[i % len(routes)]) for i in range(300)]
        reads += [http.get(f"/bus/icefloe/robot{i}/hw/wheels") for i in range(300)]  # other robots: 300 keys
        answers = await asyncio.gather(*reads)
        assert {status for status, _, _ in answers} <= {200, 503}
        after = await webapi_subscriptions(b.node)
        # The state: at most its few topics, whatever is asked; the bridge: at most MAX_CHANNELS keys.
        assert state_subscriptions(after, robot.name) <= set(STATE_KEYS)
        assert len(after) <= len(before) + len(STATE_KEYS) + MAX_CHANNELS, after
        assert http.proc.alive()


async def test_state_is_unfollowed_after_idle_and_followed_again_on_the_next_read(robot):
    async with robot.node("webapi") as node, board(robot) as b:
        state = State(node, idle_s=0.6)
        b.ticks = [5, 6]
        wheels = await state.get(keys.WHEELS, wait=5.0)
        assert (wheels.ticks_left, wheels.ticks_right) == (5, 6)
        assert set(state.followed) == {"hw/wheels"}
        with pytest.raises(ValueError, match="does not follow camera/frames"):
            state.follow(keys.FRAMES)  # only the few state topics, ever
        deadline = time.monotonic() + 10
        while state.followed:  # nobody read it for idle_s: unsubscribed
            assert time.monotonic() < deadline, "hw/wheels still followed after the idle time"
            await asyncio.sleep(0.1)
        assert state_subscriptions(await webapi_subscriptions(b.node), robot.name) == set()
        b.ticks = [7, 8]
        wheels = await state.get(keys.WHEELS, wait=5.0)  # no stale value: the newest, after a wait
        assert (wheels.ticks_left, wheels.ticks_right) == (7, 8)
        assert await state.get(keys.DIP, wait=0.2) is None  # nothing sends it here: None after the wait
        state.close()
