"""The oled service: keeps the little screen up to date.

    python -m icefloe.services.oled --config deploy/robots/sim.toml

Inputs: ``power/battery``, ``hw/wheels``, ``hw/loop``, ``odom/pose``, ``log``,
``oled/text``, ``oled/screen``, ``io/buttons`` (button 0: next screen, button 2:
the screen's action) and the services' liveliness tokens. Output: ``oled/frame``
and the configured sink (`sinks`).
"""

from __future__ import annotations

import array
import asyncio
import fcntl
import socket
import struct
import time
from collections.abc import Callable
from typing import Any

from icefloe.config import RobotConfig
from icefloe.errors import BadPayload, NotReachable
from icefloe.runtime import Latest, Node, run
from icefloe.schemas import keys
from icefloe.schemas import messages as m

from .frame import HEIGHT, WIDTH
from .screens import ERRORS, SCREENS, USER, Status, render, view
from .sinks import Sink, open_sink
from .terminal import MAX_TEXT

SIOCGIFADDR = 0x8915
"""Linux ioctl: the IPv4 address of an interface."""
REFRESH_S = 1.0
"""Publish the frame at least this often, s, even when nothing changed (for late viewers)."""


def ipv4_addresses() -> list[tuple[str, str]]:
    """(interface, address) of every interface with an IPv4 address, loopback left out."""
    found = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for _, name in socket.if_nameindex():
            if name == "lo":
                continue
            request = array.array("B", struct.pack("256s", name.encode()[:15]))
            try:
                fcntl.ioctl(s.fileno(), SIOCGIFADDR, request)
            except OSError:
                continue  # no IPv4 address on this interface
            found.append((name, socket.inet_ntoa(request.tobytes()[20:24])))
    return found


class Oled:
    """The screen state machine: which screen, what it shows, what the buttons do."""

    def __init__(self, node: Node, sink: Sink) -> None:
        self.node, self.sink = node, sink
        self.status = Status(hostname=socket.gethostname())
        self.index = 0
        """The screen shown (into `SCREENS`)."""
        self.latest: dict[str, Latest[Any]] = {}
        """`Status` field -> the topic it follows (`follow`)."""
        self.renders = 0
        """Frames rendered (only when what the screen shows changed)."""

    # ---------------------------------------------------------------- inputs

    def text(self, msg: m.OledText) -> None:
        """``oled/text``: append to the user screen and show it."""
        if len(msg.text) > MAX_TEXT:
            self.node.limited.warning("oled/text", "oled/text: %d characters, more than %d; dropped",
                                      len(msg.text), MAX_TEXT)
            return
        terminal = self.status.terminal
        before = terminal.replaced
        terminal.write(msg.text)
        if terminal.replaced > before:
            self.node.limited.info("oled/text glyphs", "oled/text: %d characters without a glyph shown as boxes",
                                   terminal.replaced - before)
        self.sink.user_text(msg.text)
        self.index = USER

    def screen(self, msg: m.OledScreen) -> None:
        """``oled/screen``: select a screen by number."""
        if not 0 <= msg.index < len(SCREENS):
            self.node.limited.warning("oled/screen", "oled/screen: index %d is not a screen (0..%d); ignored",
                                      msg.index, len(SCREENS) - 1)
            return
        self.index = msg.index

    def log(self, msg: m.Log) -> None:
        """``log``: an error switches to the error screen (like the PenguinPi firmware)."""
        if msg.level in ("error", "critical"):
            self.status.error, self.status.errors = msg, self.status.errors + 1
            self.index = ERRORS

    async def button(self, msg: m.Buttons) -> None:
        """``io/buttons``: 0 = next screen, 2 = this screen's action; the others are not ours."""
        if msg.button == 0:
            self.index = (self.index + max(msg.presses, 1)) % len(SCREENS)
        elif msg.button == 2:
            await self.action()

    async def action(self) -> None:
        name = SCREENS[self.index].name
        if name == "user":
            self.status.terminal.clear()
        elif name == "errors":
            self.status.error = None
        elif name in ("encoders", "pose"):
            if name == "encoders" and self.status.wheels is not None:
                w = self.status.wheels
                self.status.tick_zero = (w.ticks_left, w.ticks_right)
            try:
                await self.node.query(keys.ODOM_RESET, m.PoseReset(), timeout=1.0)
            except (NotReachable, BadPayload) as exc:
                self.node.limited.warning("button 2", "button 2 on %s: %s", name, exc)

    # ---------------------------------------------------------------- loops

    def follow(self, topic: keys.Topic, field: str) -> None:
        """Keep ``status.<field>`` set to the latest message of ``topic``, read at each frame
        (`Node.latest`: nothing runs here for the 100 wheel messages a second the screen
        shows five times a second)."""
        self.latest[field] = self.node.latest(topic)

    def update(self) -> None:
        """The newest message of each followed topic into `status`."""
        for field, latest in self.latest.items():
            msg = latest.get()
            if msg is not None:
                setattr(self.status, field, msg)

    async def poll_services(self, period: float = 2.0) -> None:
        prefix = keys.alive_key(self.node.robot, "")
        while True:
            alive = await self.node.alive()
            self.status.alive = [k.removeprefix(prefix) for k in alive]
            self.status.addresses = await asyncio.to_thread(ipv4_addresses)
            await asyncio.sleep(period)

    async def show(self, rate_hz: float) -> None:
        """Look at ``rate_hz``; render, publish and show a frame only when what the screen shows
        changed (`screens.view`); publish the same frame again every REFRESH_S for late viewers."""
        pub = self.node.publisher(keys.OLED_FRAME)
        shown: tuple[object, ...] | None = None
        message: m.OledFrame | None = None
        last_sent = 0.0
        while True:
            self.update()
            now = time.monotonic()
            seen = view(self.index, self.status)
            if seen != shown:
                frame = render(self.index, self.status)
                self.renders += 1
                message = m.OledFrame(width=WIDTH, height=HEIGHT, pixels=frame.pack())
                pub.put(message)
                await self.sink.show(frame, self.index)
                shown, last_sent = seen, now
            elif message is not None and now - last_sent >= REFRESH_S:
                pub.put(message)
                last_sent = now
            await asyncio.sleep(1.0 / rate_hz)


async def main(config: RobotConfig) -> None:
    async with Node("oled", config) as node:
        sink = open_sink(node, config.display)
        oled = Oled(node, sink)

        async def each(topic: keys.Topic, handle: Callable[[Any], object]) -> None:
            # fifo: every command, text and button press counts, in order.
            async for msg in node.subscribe(topic, latest=False):
                result = handle(msg)
                if asyncio.iscoroutine(result):
                    await result

        try:
            async with asyncio.TaskGroup() as tasks:
                oled.follow(keys.BATTERY, "battery")
                oled.follow(keys.WHEELS, "wheels")
                oled.follow(keys.LOOP, "loop")
                oled.follow(keys.ODOM_POSE, "pose")
                tasks.create_task(each(keys.LOG, oled.log))
                tasks.create_task(each(keys.OLED_TEXT, oled.text))
                tasks.create_task(each(keys.OLED_SCREEN, oled.screen))
                tasks.create_task(each(keys.BUTTONS, oled.button))
                tasks.create_task(oled.poll_services())
                tasks.create_task(oled.show(config.display.rate_hz))
        finally:
            sink.close()


if __name__ == "__main__":
    run(main)
