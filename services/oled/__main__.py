"""The oled service: keeps the little screen up to date.

    python -m icefloe.services.oled --config deploy/robots/sim.toml

Inputs: ``power/battery``, ``hw/wheels``, ``hw/loop``, ``hw/hold``, ``odom/pose``, ``log``,
``oled/text``, ``oled/screen``, ``io/buttons`` (button 0: next screen, button 2:
the screen's action) and the services' liveliness tokens. Output: ``oled/frame``
and the configured sink (`sinks`).

A screen that has not changed costs (almost) nothing (bench/stack_cpu.py measures it): one
loop wakes at ``display.rate_hz`` and does everything; the commands wait in Zenoh until then
(no thread waits for them); the fast streams (``hw/wheels`` and ``odom/pose`` at
50 Hz) are followed only while a screen shows them; the liveliness tokens are asked for only
while the services screen is shown; a frame is rendered only when what it shows changed.
"""

from __future__ import annotations

import array
import asyncio
import contextlib
import fcntl
import socket
import struct
import time
from collections.abc import Callable
from typing import Any

from icefloe.config import RobotConfig
from icefloe.errors import BadPayload, NotReachable
from icefloe.runtime import Batches, Latest, Node, run
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
POLL_S = 2.0
"""Read the addresses (network screen) or ask for the liveliness tokens (services screen) this
often while that screen is shown, s."""
ALWAYS: dict[str, keys.Topic] = {"battery": keys.BATTERY, "loop": keys.LOOP, "hold": keys.HOLD}
"""`Status` field -> topic, followed all the time: the battery inverts every screen, the lab's
hold replaces every screen; hw/loop comes once a second (following it on demand would leave the
timing screen empty for a second)."""
ON_DEMAND: dict[str, keys.Topic] = {"wheels": keys.WHEELS, "pose": keys.ODOM_POSE}
"""`Status` field -> topic, followed only while the screen shown reads the field: 150 messages a
second that Zenoh would otherwise deliver to a screen that does not show them."""
INPUT_BACKLOG = 64
"""Messages of each command key kept for the next frame (a flood loses its oldest)."""
FIRST_SAMPLE_S = 0.3
"""After a screen that shows an on-demand topic comes up, wait at most this long for its first
message before rendering "no ... yet", s (they come at 50 Hz and more)."""


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
        self.switched = asyncio.Event()
        """Set when the screen shown changes (`poll` asks at once for what the new one shows)."""
        self._index = 0
        self.latest: dict[str, Latest[Any]] = {}
        """`Status` field -> the subscription it follows now (`follow`)."""
        self.renders = 0
        """Frames rendered (only when what the screen shows changed)."""
        self.resetting: asyncio.Task[None] | None = None
        """The ``odom/reset`` query of button 2, while it runs."""

    @property
    def index(self) -> int:
        """The screen shown (into `SCREENS`)."""
        return self._index

    @index.setter
    def index(self, value: int) -> None:
        if value != self._index:
            self._index = value
            self.switched.set()

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

    def button(self, msg: m.Buttons) -> None:
        """``io/buttons``: 0 = next screen, 2 = this screen's action; the others are not ours."""
        if msg.button == 0:
            self.index = (self.index + max(msg.presses, 1)) % len(SCREENS)
        elif msg.button == 2:
            self.action()

    def action(self) -> None:
        name = SCREENS[self.index].name
        if name == "user":
            self.status.terminal.clear()
        elif name == "errors":
            self.status.error = None
        elif name in ("encoders", "pose"):
            if name == "encoders" and self.status.wheels is not None:
                w = self.status.wheels
                self.status.tick_zero = (w.ticks_left, w.ticks_right)
            if self.resetting is None or self.resetting.done():  # one at a time, however many presses
                self.resetting = asyncio.create_task(self.reset_odometry(name))

    async def reset_odometry(self, screen: str) -> None:
        try:
            await self.node.query(keys.ODOM_RESET, m.PoseReset(), timeout=1.0)
        except (NotReachable, BadPayload) as exc:
            self.node.limited.warning("button 2", "button 2 on %s: %s", screen, exc)

    def inputs(self, period: float) -> list[tuple[Batches[Any], Callable[[Any], None]]]:
        """The commands, each with its handler: ``log``, ``oled/text``, ``oled/screen``,
        ``io/buttons``. Every one counts, in order; they are taken once a frame (`take`), so no
        Python runs per message and no thread waits for them between frames. (Within one
        frame a screen asked for wins over an error's or a text's own switch.)"""
        return [(self.node.batches(topic, period, maxsize=INPUT_BACKLOG), handle) for topic, handle in
                ((keys.LOG, self.log), (keys.OLED_TEXT, self.text), (keys.OLED_SCREEN, self.screen),
                 (keys.BUTTONS, self.button))]

    # ---------------------------------------------------------------- loops

    def follow(self) -> list[Latest[Any]]:
        """Follow the topics the shown screen reads (`ALWAYS`, and those of `ON_DEMAND` it shows),
        stop following the others. Returns the subscriptions just made. Each is read at the
        next frame (`Node.latest`: nothing runs here for the 100 wheel messages a second the
        screen shows five times a second)."""
        reads = SCREENS[self.index].reads
        wanted = {**ALWAYS, **{f: t for f, t in ON_DEMAND.items() if f in reads}}
        for field in self.latest.keys() - wanted.keys():
            self.latest.pop(field).undeclare()
            setattr(self.status, field, None)  # never shown stale when its screen comes back
        made = {f: self.node.latest(wanted[f]) for f in wanted.keys() - self.latest.keys()}
        self.latest.update(made)
        return list(made.values())

    def update(self) -> None:
        """The newest message of each followed topic into `status`."""
        for field, latest in self.latest.items():
            msg = latest.get()
            if msg is not None:
                setattr(self.status, field, msg)

    async def poll(self, period: float = POLL_S) -> None:
        """What no message brings: the addresses while the network screen is shown, the services
        alive while the services screen is; at once when one comes up, then every ``period``."""
        prefix = keys.alive_key(self.node.robot, "")
        while True:
            self.switched.clear()
            name = SCREENS[self.index].name
            if name == "network":
                self.status.addresses = ipv4_addresses()  # a few ioctls: microseconds
            elif name == "services":
                alive = await self.node.alive()
                self.status.alive = [k.removeprefix(prefix) for k in alive]
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(period):
                    await self.switched.wait()

    async def show(self, rate_hz: float) -> None:
        """Each frame (``rate_hz``): take the commands that came, then render, publish and show a
        frame only when what the screen shows changed (`screens.view`); publish the same frame
        again every REFRESH_S for late viewers."""
        pub = self.node.publisher(keys.OLED_FRAME)
        inputs = self.inputs(1.0 / rate_hz)
        shown: tuple[object, ...] | None = None
        message: m.OledFrame | None = None
        last_sent = 0.0
        while True:
            for batches, handle in inputs:
                for msg in batches.take():
                    handle(msg)
            made = self.follow()
            deadline = time.monotonic() + FIRST_SAMPLE_S
            while any(latest.get() is None for latest in made) and time.monotonic() < deadline:
                await asyncio.sleep(0.01)  # a screen just shown: its first message, not "no ... yet"
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
        try:
            async with asyncio.TaskGroup() as tasks:
                tasks.create_task(oled.poll())
                tasks.create_task(oled.show(config.display.rate_hz))
        finally:
            sink.close()


if __name__ == "__main__":
    run(main)
