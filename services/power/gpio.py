"""GPIO backends: where the shutdown button, the request line and the acknowledge line live.

The service sees one small interface, `Lines`, and cannot tell the backends apart:

* ``gpiod``: the Raspberry Pi's lines through libgpiod v2 (``pip install gpiod``;
  imported only when chosen). Edge times come from the kernel (CLOCK_MONOTONIC).
* ``sim``: the simulator's lines on the bus key ``sim/gpio`` (`GpioLevel`).
  Edge times are the publisher's stamps (epoch), so bounce timing survives the bus.
* ``none``: no lines (a laptop, a robot without the shutdown wiring).

Levels are physical: 1 = high, 0 = low. All three lines are active low.
"""

from __future__ import annotations

import asyncio
import datetime
import time
from collections.abc import AsyncIterator
from typing import Any, Protocol

from icefloe.config import Power
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m

Edge = tuple[int, int, float]
"""(BCM line, new level 0/1, time in s on the backend's `clock`)."""


class Lines(Protocol):
    """The GPIO lines of the power service."""

    def clock(self) -> float:
        """Now, s, on the clock that edge times use."""
        ...

    def edges(self) -> AsyncIterator[Edge]:
        """Level changes of the input lines (first the current levels, then each change)."""
        ...

    def drive(self, line: int, level: int) -> None:
        """Set an output line high (1) or low (0)."""
        ...

    def refresh(self) -> None:
        """Called about once a second: say the output levels again if the medium can lose them."""
        ...

    def close(self) -> None: ...


class SimLines:
    """The simulator's lines, as `GpioLevel` samples on ``sim/gpio``."""

    def __init__(self, node: Node, inputs: set[int]) -> None:
        self._node, self._inputs = node, inputs
        # fifo, not latest: every edge of a bounce burst matters for the debounce.
        self._sub = node.subscribe(keys.SIM_GPIO, latest=False, maxsize=256)
        self._pub = node.publisher(keys.SIM_GPIO)
        self._outputs: dict[int, int] = {}

    def clock(self) -> float:
        return time.time()

    async def edges(self) -> AsyncIterator[Edge]:
        async for sample in self._sub:
            if sample.line not in self._inputs:
                continue  # another line (e.g. our own acknowledge line echoed back)
            if sample.level not in (0, 1):
                self._node.limited.warning("sim/gpio", "sim/gpio: line %d: level must be 0 or 1, got %d; "
                                           "ignored", sample.line, sample.level)
                continue
            yield sample.line, sample.level, sample.stamp / 1e9

    def drive(self, line: int, level: int) -> None:
        self._outputs[line] = level
        self._pub.put(m.GpioLevel(stamp=time.time_ns(), line=line, level=level))

    def refresh(self) -> None:
        # A simulator that starts after us (or restarts) missed our edges: repeat the levels.
        for line, level in self._outputs.items():
            self._pub.put(m.GpioLevel(stamp=time.time_ns(), line=line, level=level))

    def close(self) -> None:
        self._sub.close()


class GpiodLines:
    """The Raspberry Pi's lines through libgpiod v2 (Pi only; not testable on a PC)."""

    def __init__(self, chip: str, inputs: set[int], outputs: dict[int, int]) -> None:
        try:
            import gpiod
            from gpiod.line import Bias, Direction, Value
            from gpiod.line import Edge as GpiodEdge
        except ImportError:
            raise RuntimeError("power.gpio = \"gpiod\" needs the gpiod package (pip install gpiod)") from None
        self._gpiod, self._value = gpiod, Value
        self._inputs = sorted(inputs)
        config: dict[Any, Any] = {
            tuple(self._inputs): gpiod.LineSettings(
                direction=Direction.INPUT, bias=Bias.PULL_UP, edge_detection=GpiodEdge.BOTH),
        }
        for line, level in outputs.items():
            config[line] = gpiod.LineSettings(
                direction=Direction.OUTPUT, output_value=Value.ACTIVE if level else Value.INACTIVE)
        self._request = gpiod.request_lines(chip, consumer="icefloe-power", config=config)

    def clock(self) -> float:
        return time.monotonic()  # libgpiod stamps edges with CLOCK_MONOTONIC

    def _wait_events(self) -> list[Edge]:
        # Blocking, so it runs in a worker thread; the short timeout lets cancellation through.
        if not self._request.wait_edge_events(datetime.timedelta(seconds=0.2)):
            return []
        rising = self._gpiod.EdgeEvent.Type.RISING_EDGE
        return [(e.line_offset, 1 if e.event_type == rising else 0, e.timestamp_ns / 1e9)
                for e in self._request.read_edge_events()]

    async def edges(self) -> AsyncIterator[Edge]:
        now = self.clock()
        for line in self._inputs:
            yield line, 1 if self._request.get_value(line) == self._value.ACTIVE else 0, now
        while True:
            for edge in await asyncio.to_thread(self._wait_events):
                yield edge

    def drive(self, line: int, level: int) -> None:
        self._request.set_value(line, self._value.ACTIVE if level else self._value.INACTIVE)

    def refresh(self) -> None:
        pass  # a real line keeps its level

    def close(self) -> None:
        self._request.release()


class NoLines:
    """No GPIO at all: no button, no request line; driving a line does nothing."""

    def clock(self) -> float:
        return time.monotonic()

    async def edges(self) -> AsyncIterator[Edge]:
        await asyncio.Event().wait()  # never any edge
        yield (0, 1, 0.0)  # pragma: no cover - unreachable, makes this an async generator

    def drive(self, line: int, level: int) -> None:
        pass

    def refresh(self) -> None:
        pass

    def close(self) -> None:
        pass


def open_lines(node: Node, power: Power) -> Lines:
    """The backend named by ``power.gpio``; the service drives the acknowledge line high
    ("daemon alive") once it is listening."""
    inputs = {power.button_line, power.request_line}
    if power.gpio == "gpiod":
        # Requested high at once: after a restart of this service a low pulse would be a
        # fall after high, which the PenguinPi firmware takes as "the Pi is shutting down".
        return GpiodLines(power.gpio_chip, inputs, {power.ack_line: 1})
    if power.gpio == "sim":
        return SimLines(node, inputs)
    return NoLines()
