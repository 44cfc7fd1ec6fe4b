"""oled as a real process: frames on the bus, screens, buttons, errors, bad text,
the PenguinPi sink (``io/screen``, ``io/text``) and low-battery inversion.

Expected frames come from the pure renderer (itself pinned by the golden images
in test_oled_render.py), fed the same messages the test sends to the process.
"""

from __future__ import annotations

import asyncio
import time
from typing import Any

from conftest import Robot, wait_for

from icefloe.runtime import MSGPACK, Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.oled.frame import Frame
from icefloe.services.oled.screens import Status, render
from icefloe.services.oled.terminal import Terminal


class Viewer:
    """Everything the oled process sends, as it arrives."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.frames: list[Frame] = []
        self.board_screens: list[int] = []
        self.board_texts: list[str] = []
        self.logs: list[m.Log] = []
        self.resets = 0
        node.queryable(keys.ODOM_RESET, self._reset)
        self._tasks = [asyncio.create_task(self._collect(t)) for t in
                       (keys.OLED_FRAME, keys.BOARD_SCREEN, keys.BOARD_TEXT, keys.LOG)]

    async def _collect(self, topic: keys.Topic) -> None:
        async for msg in self.node.subscribe(topic, latest=False, maxsize=1024):
            if isinstance(msg, m.OledFrame):
                assert (msg.width, msg.height, len(msg.pixels)) == (128, 32, 512)
                self.frames.append(Frame.unpack(msg.pixels))
            elif isinstance(msg, m.OledScreen):
                self.board_screens.append(msg.index)
            elif isinstance(msg, m.OledText):
                self.board_texts.append(msg.text)
            elif isinstance(msg, m.Log) and msg.service == "oled":
                self.logs.append(msg)

    async def _reset(self, request: m.PoseReset) -> m.Pose:
        self.resets += 1
        return m.Pose(stamp=time.time_ns(), x=request.x, y=request.y, theta=request.theta)

    async def shows(self, expected: Frame, timeout: float = 15.0) -> None:
        """Wait until the latest frame is ``expected`` (printing both if it never is)."""
        try:
            await wait_for(lambda: self.frames and self.frames[-1] == expected, timeout=timeout)
        except AssertionError:
            last = self.frames[-1].ascii() if self.frames else "(no frame)"
            raise AssertionError(f"expected:\n{expected.ascii()}\ngot:\n{last}") from None

    def logged(self, text: str) -> bool:
        return any(text in lg.text for lg in self.logs)

    def close(self) -> None:
        for task in self._tasks:
            task.cancel()


async def stream(pub: Any, message: m.Message, period: float = 0.02) -> None:
    """Put ``message`` every ``period`` s until cancelled (a sensor's stream)."""
    while True:
        pub.put(message)
        await asyncio.sleep(period)


async def test_text_buttons_errors_and_the_penguinpi_sink(robot: Robot) -> None:
    async with robot.node() as node:
        viewer = Viewer(node)
        oled = robot.start("oled")  # sim.toml: display.kind = "penguinpi"
        await wait_for(lambda: viewer.frames, timeout=15)
        assert viewer.board_screens[:1] == [0]  # starts on the network screen
        say = node.publisher(keys.OLED_TEXT)
        press = node.publisher(keys.BUTTONS)

        # User text: rendered by us, and forwarded to the firmware's own user screen.
        terminal = Terminal()
        for text in ("hello\n", "robot ", "é\x07!"):
            say.put(m.OledText(text=text))
            terminal.write(text)
        await viewer.shows(render(1, Status(terminal=terminal)))
        await wait_for(lambda: viewer.board_texts == ["hello\n", "robot ", "??!"])
        assert 1 in viewer.board_screens
        await wait_for(lambda: viewer.logged("1 characters without a glyph shown as boxes"))

        # Bad text: too long (dropped, logged), not UTF-8 (dropped by the runtime, logged).
        say.put(m.OledText(text="x" * 5000))
        node.session.put(node.key(keys.OLED_TEXT), b"\x81\xa4text\xa2\xff\xfe", encoding=MSGPACK)
        await wait_for(lambda: viewer.logged("5000 characters, more than 1024; dropped"))
        await wait_for(lambda: viewer.logged(f"{node.key(keys.OLED_TEXT)}: not valid MessagePack"))
        say.put(m.OledText(text="\fstill here"))  # ... and the service still works
        terminal.write("\fstill here")
        await viewer.shows(render(1, Status(terminal=terminal)))

        # Button 2 on the user screen clears it; button 0 moves on to the battery screen.
        press.put(m.Buttons(stamp=time.time_ns(), button=2))
        await viewer.shows(render(1, Status()))
        press.put(m.Buttons(stamp=time.time_ns(), button=0))
        await viewer.shows(render(2, Status()))
        await wait_for(lambda: viewer.board_screens[-1] == 2)

        # An error anywhere switches to the error screen; button 2 clears it.
        error = m.Log(stamp=1, level="error", service="hwbridge", text="/dev/serial0: no reply")
        node.publisher(keys.LOG).put(error)
        await viewer.shows(render(7, Status(error=error, errors=1)))
        press.put(m.Buttons(stamp=time.time_ns(), button=2))
        await viewer.shows(render(7, Status(errors=1)))

        # Encoders (screen 3): button 2 zeroes the counts shown and resets odometry. oled follows
        # hw/wheels only while a screen shows it: send them as hwbridge does, again and again.
        node.publisher(keys.OLED_SCREEN).put(m.OledScreen(index=3))
        wheels = m.Wheels(stamp=1, ticks_left=500, ticks_right=-20, speed_left=0.1,
                          speed_right=0.1)
        wheels_pub = node.publisher(keys.WHEELS)
        streaming = asyncio.create_task(stream(wheels_pub, wheels))
        await viewer.shows(render(3, Status(wheels=wheels)))
        press.put(m.Buttons(stamp=time.time_ns(), button=2))
        await viewer.shows(render(3, Status(wheels=wheels, tick_zero=(500, -20))))
        await wait_for(lambda: viewer.resets == 1)

        node.publisher(keys.OLED_SCREEN).put(m.OledScreen(index=42))
        await wait_for(lambda: viewer.logged("index 42 is not a screen"))
        streaming.cancel()
        assert oled.stop() == 0
        viewer.close()


async def test_low_battery_inverts_the_display_and_services_are_listed(make_robot: Any) -> None:
    robot: Robot = make_robot('[display]\nkind = "none"\n')
    async with robot.node() as node:
        viewer = Viewer(node)
        oled = robot.start("oled")
        await wait_for(lambda: viewer.frames, timeout=15)
        node.publisher(keys.OLED_SCREEN).put(m.OledScreen(index=2))
        battery = node.publisher(keys.BATTERY)
        for volts, state in ((7.4, "ok"), (6.9, "low"), (6.4, "critical"), (7.8, "ok")):
            reading = m.Battery(stamp=1, voltage=volts, current=0.3, state=state)  # type: ignore[arg-type]
            battery.put(reading)
            expected = render(2, Status(battery=reading))
            await viewer.shows(expected)
            title_corner = expected.pixels[0:8, 126:128]  # lit in the title bar unless inverted
            assert title_corner.all() == (state == "ok")
        assert viewer.board_screens == []  # kind = "none": nothing sent to the board

        # The services screen lists the liveliness tokens: the router, oled, and us.
        node.publisher(keys.OLED_SCREEN).put(m.OledScreen(index=6))
        alive = ["oled", "router", "tester"]
        await viewer.shows(render(6, Status(alive=alive, battery=reading)))
        assert oled.stop() == 0
        viewer.close()


async def test_fast_streams_are_followed_only_while_a_screen_shows_them(make_robot: Any) -> None:
    """At rest the screen costs nothing: oled subscribes to hw/wheels and odom/pose
    (50 Hz each) only while a screen shows them (Zenoh's matching status says whether anyone
    listens), shows what comes after it looks again, never what it saw before, and a student
    flipping screens a few hundred times leaves it as it was."""
    robot: Robot = make_robot('[display]\nkind = "none"\n')
    async with robot.node() as node:
        viewer = Viewer(node)
        wheels_pub, pose_pub = node.publisher(keys.WHEELS), node.publisher(keys.ODOM_POSE)
        screen = node.publisher(keys.OLED_SCREEN)
        oled = robot.start("oled")
        await wait_for(lambda: viewer.frames, timeout=15)
        await asyncio.sleep(1.0)  # settled: had it subscribed, Zenoh would say so by now
        assert not wheels_pub.matched and not pose_pub.matched  # the network screen shows neither

        screen.put(m.OledScreen(index=3))
        await wait_for(lambda: wheels_pub.matched, timeout=15)
        assert not pose_pub.matched
        old = m.Wheels(stamp=1, ticks_left=7, ticks_right=8, speed_left=0.0, speed_right=0.0)
        streaming = asyncio.create_task(stream(wheels_pub, old))
        await viewer.shows(render(3, Status(wheels=old)))
        streaming.cancel()

        screen.put(m.OledScreen(index=8))  # pose: wheels no longer followed, the pose is
        await wait_for(lambda: pose_pub.matched and not wheels_pub.matched, timeout=15)
        screen.put(m.OledScreen(index=3))  # back, nothing sent since: no stale counts
        await viewer.shows(render(3, Status()))

        for i in range(300):  # flipping screens
            screen.put(m.OledScreen(index=(3, 8, 0)[i % 3]))
            await asyncio.sleep(0.005)
        await wait_for(lambda: not wheels_pub.matched and not pose_pub.matched, timeout=15)
        new = m.Wheels(stamp=2, ticks_left=9, ticks_right=10, speed_left=0.0, speed_right=0.0)
        streaming = asyncio.create_task(stream(wheels_pub, new))
        screen.put(m.OledScreen(index=4))  # motors: wheels again
        await viewer.shows(render(4, Status(wheels=new)))
        streaming.cancel()
        assert oled.stop() == 0
        assert "Traceback" not in oled.output
        viewer.close()
