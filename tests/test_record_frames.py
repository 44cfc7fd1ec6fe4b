"""Who follows "every key of the robot" leaves ``camera/frames`` out, and the camera at rest:
``icefloe record`` with no keys, ``icefloe topics``, ``echo``/``hz`` of ``**``, the robot's page (the HTTP bridge's
``/bus/icefloe/<robot>/**`` event stream). Asked for by name, the frames come.

The camera sends ``camera/frames`` only while a subscriber matches it (Zenoh's matching
status): a stand-in camera's publisher here, watched while the real processes run against
the robot's real router. About 90 s on a busy 2-core machine.
"""

from __future__ import annotations

import asyncio
import time

import pytest
from conftest import Robot, wait_for
from test_bag_cli import cli, icefloe
from webapi_helpers import webapi, webapi_robot

from icefloe.bag import Bag
from icefloe.schemas import keys
from icefloe.schemas import messages as m


async def record_while_publishing(robot: Robot, *args: str) -> tuple[set[str], bool]:
    """Run ``icefloe record -o FILE --duration 3 <args>`` while this process publishes hw/wheels,
    camera/image, a key of the robot's own program and camera/frames (the last only while matched, as
    the camera does); returns the keys recorded, and whether camera/frames was ever matched."""
    out = robot.tmp / f"rec{len(robot.procs)}.mcap"
    recorder = cli(robot, "record", "-o", str(out), "--duration", "3", *args, name="record")
    matched = False
    async with robot.node("tester") as node:
        frames, wheels, image = (node.publisher(t) for t in (keys.FRAMES, keys.WHEELS, keys.IMAGE))
        await wait_for(lambda: "recording" in recorder.output, timeout=30)
        deadline = time.monotonic() + 2.5
        while time.monotonic() < deadline:
            now = time.time_ns()
            matched |= frames.matched
            if frames.matched:
                frames.put(m.Image(stamp=now, width=1, height=1, data=b"\xff\xd8"))
            wheels.put(m.Wheels(stamp=now, ticks_left=1, ticks_right=2, speed_left=0.0, speed_right=0.0))
            image.put(m.Image(stamp=now, width=1, height=1, data=b"\xff\xd8"))
            node.session.put(node.key("student/a/b"), b'{"x": 1}', encoding="application/json")
            await asyncio.sleep(0.05)
    assert recorder.popen.wait(20) == 0, recorder.output
    return {e.channel.key for e in Bag([out]).entries()}, matched


async def test_record_with_no_keys_leaves_camera_frames_out_and_the_camera_at_rest(robot: Robot) -> None:
    recorded, matched = await record_while_publishing(robot)
    key = lambda name: f"icefloe/{robot.name}/{name}"  # noqa: E731
    assert not matched, "icefloe record with no keys switched camera/frames on"
    assert key("camera/frames") not in recorded
    assert {key("hw/wheels"), key("camera/image"), key("student/a/b")} <= recorded, recorded
    assert "but camera/frames (--frames records it)" in robot.procs[-1].output


async def test_record_frames_asks_for_them(robot: Robot) -> None:
    recorded, matched = await record_while_publishing(robot, "--frames")
    assert matched
    assert f"icefloe/{robot.name}/camera/frames" in recorded
    assert f"icefloe/{robot.name}/hw/wheels" in recorded


@pytest.mark.timeout(400)  # four command-line runs: each starts a Python, slow on a busy machine
async def test_topics_and_the_robots_page_leave_the_camera_at_rest_and_frames_by_name_wake_it(make_robot) -> None:
    robot = webapi_robot(make_robot)
    async with robot.node("camera") as node, webapi(robot) as http:
        frames = node.publisher(keys.FRAMES)

        async def watch(seconds: float) -> bool:
            seen, deadline = False, time.monotonic() + seconds
            while time.monotonic() < deadline:
                seen |= frames.matched
                await asyncio.sleep(0.02)
            return seen

        async def matched_while(*args: str) -> tuple[bool, str]:
            """Whether camera/frames was matched while ``icefloe <args>`` ran (start to end)."""
            seen, done = False, asyncio.Event()

            async def look() -> None:
                nonlocal seen
                while not done.is_set():
                    seen |= frames.matched
                    await asyncio.sleep(0.02)

            looking = asyncio.create_task(look())
            _, out, err = await icefloe(*args, "--config", str(robot.config_path), timeout=150.0)
            done.set()
            await looking
            return seen, out + err

        seen, out = await matched_while("topics", "--duration", "3")
        assert "camera/frames" in out  # listed from the key table, not subscribed to
        assert not seen, "icefloe topics switched camera/frames on"
        for verb in ("echo", "hz"):  # every key of the robot: the same
            seen, _ = await matched_while(verb, "**", "--duration", "2")
            assert not seen, f"icefloe {verb} '**' switched camera/frames on"
        seen, _ = await matched_while("echo", "camera/frames", "--duration", "2")
        assert seen, "icefloe echo camera/frames did not subscribe to it"
        # The robot's page: every key of the robot, as Server-Sent Events.
        page = asyncio.create_task(http.events(f"/bus/icefloe/{robot.name}/**", 1000, timeout=4.0, _rate="10"))
        assert not await watch(3.0), "the page's event stream switched camera/frames on"
        page.cancel()
        await asyncio.gather(page, return_exceptions=True)
        # Asked by name, the frames are followed.
        asked = asyncio.create_task(http.events("/bus/camera/frames", 1000, timeout=6.0))
        deadline = time.monotonic() + 5
        while not frames.matched:
            assert time.monotonic() < deadline, "/bus/camera/frames did not subscribe to camera/frames"
            await asyncio.sleep(0.05)
        asked.cancel()
        await asyncio.gather(asked, return_exceptions=True)
