"""The shutdown sequence, strictly in order, run at most once.

1. publish ``power/shutdown`` (a `ShutdownNotice` with the reason): everyone
   learns why the robot is going away;
2. query ``cmd/halt`` and wait for hwbridge's answer that the wheels have
   stopped (no answer within ``halt_timeout_s`` -> log an error and go on: a
   dead bridge must not keep a robot with a flat battery running); a refusal
   (a program drove again after the stop) -> ask again while that time lasts;
3. drop the acknowledge line (GPIO11) low: the PenguinPi firmware shows
   "TURN RaspberryPI OFF SAFELY" and stops its timers; wait ``ack_delay_s``;
4. run ``power.poweroff_command`` (``true`` in the simulator and tests).
"""

from __future__ import annotations

import asyncio
import time

from icefloe.config import Power
from icefloe.errors import BadPayload, NotReachable
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m

from .gpio import Lines

STOPPED_SPEED = 0.01
"""Wheel rim speeds below this count as stopped, m/s."""
HALT_RETRY_S = 0.1
"""After hwbridge refuses a halt, ask again this much later, s."""


class Shutdown:
    """Starts the sequence once; later triggers get the first notice back."""

    def __init__(self, node: Node, power: Power, lines: Lines) -> None:
        self._node, self._power, self._lines = node, power, lines
        self._notice_pub = node.publisher(keys.SHUTDOWN)
        self.notice: m.ShutdownNotice | None = None
        """The notice of the shutdown under way (None while running normally)."""
        self.done = asyncio.Event()
        """Set when the power-off command has run."""
        self._task: asyncio.Task[None] | None = None

    def start(self, reason: str) -> m.ShutdownNotice:
        """Begin shutting down for ``reason`` (idempotent); returns the notice that was published."""
        if self.notice is not None:
            self._node.limited.info("shutting down", "already shutting down (%s); ignoring %r",
                                    self.notice.reason, reason)
            return self.notice
        self.notice = m.ShutdownNotice(stamp=time.time_ns(), reason=reason)
        self._notice_pub.put(self.notice)
        self._node.log.warning("shutting down: %s", reason)
        self._task = asyncio.create_task(self._finish())
        return self.notice

    async def _finish(self) -> None:
        log, power = self._node.log, self._power
        await self._halt()
        self._lines.drive(power.ack_line, 0)
        await asyncio.sleep(power.ack_delay_s)
        command = power.poweroff_command
        log.warning("running %s", " ".join(command))
        try:
            proc = await asyncio.create_subprocess_exec(*command)
            code = await proc.wait()
        except OSError as exc:
            log.error("power.poweroff_command %s failed to start: %s", command, exc)
        else:
            if code != 0:
                log.error("power.poweroff_command %s exited with %d", command, code)
        self.done.set()

    async def _halt(self) -> None:
        """Ask hwbridge to stop the wheels, again while it refuses and ``halt_timeout_s`` lasts.

        hwbridge refuses a halt when a motion command issued after it released the stop before
        the board confirmed it: a program still driving as the shutdown begins. Each new halt
        is a new stop, so once that program stops (or its commands stop coming) one holds."""
        log, loop = self._node.log, asyncio.get_running_loop()
        deadline = loop.time() + self._power.halt_timeout_s
        while True:
            try:
                wheels = await self._node.query(keys.HALT, m.Halt(),
                                                timeout=max(deadline - loop.time(), HALT_RETRY_S))
            except (BadPayload, NotReachable) as exc:
                # BadPayload is an error reply (refused, or the board did not confirm): ask again
                # while time lasts. NotReachable: no answer within all of it.
                if isinstance(exc, BadPayload) and loop.time() + HALT_RETRY_S < deadline:
                    self._node.limited.warning("cmd/halt", "cmd/halt refused (%s); asking again", exc)
                    await asyncio.sleep(HALT_RETRY_S)
                    continue
                log.error("no wheel-stop confirmation (%s); powering off anyway", exc)
                return
            speeds = (wheels.speed_left, wheels.speed_right)
            if max(abs(v) for v in speeds) < STOPPED_SPEED:
                log.info("hwbridge confirmed the wheels stopped")
            else:  # hwbridge answers after its own timeout even if they still turn
                log.error("hwbridge answered but the wheels still turn (%.3f, %.3f m/s); "
                          "powering off anyway", *speeds)
            return

    async def request(self, request: m.ShutdownRequest) -> m.ShutdownNotice:
        """The ``power/request`` queryable: answer with the notice once it is published."""
        # The reason ends up in logs and on screens: printable characters only, bounded length.
        reason = "".join(c for c in request.reason if c.isprintable()).strip()[:80]
        return self.start(reason or "requested on the bus")
