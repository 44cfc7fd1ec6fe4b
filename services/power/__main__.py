"""The power service: battery monitor and shutdown manager.

    python -m icefloe.services.power --config deploy/robots/sim.toml

Reads ``hw/battery`` (raw, from hwbridge), publishes ``power/battery`` (filtered,
with a state), watches the shutdown button and the board's request line, answers
``power/request``, and runs the shutdown sequence (`shutdown.Shutdown`). Short presses and
releases of the shutdown button go out on ``io/buttons`` (button 10), for programs.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

from icefloe.config import Power, RobotConfig
from icefloe.runtime import Batches, Node, run
from icefloe.schemas import keys
from icefloe.schemas import messages as m

from .battery import READ_BACKLOG, READ_PERIOD_S, BadReading, BatteryMonitor
from .gpio import Lines, open_lines
from .lines import HoldDetector
from .shutdown import Shutdown


def battery_readings(node: Node, power: Power) -> Batches[m.BatteryReading]:
    """Every ``hw/battery`` reading, in order (persistence counts consecutive ones), as a list
    each `READ_PERIOD_S`: Zenoh keeps them meanwhile, and no Python runs per reading."""
    return node.batches(keys.HW_BATTERY, min(READ_PERIOD_S, power.silent_s / 4), maxsize=READ_BACKLOG)


async def watch_battery(node: Node, power: Power, readings: Batches[m.BatteryReading],
                        shutdown: Shutdown) -> None:
    """hw/battery -> power/battery (once a batch: twice a second); shut down once critical has
    persisted, or on silence while low."""
    if power.source == "i2c":
        node.log.error("power.source = \"i2c\": no I2C battery monitor driver in this build; "
                       "battery not monitored (use \"board\")")
        return
    # "board" and "sim" read the same key: the simulator's battery reaches us through
    # its board model and hwbridge, exactly like the real one.
    monitor = BatteryMonitor(power.low_v, power.critical_v, power.critical_readings, power.pole)
    battery = node.publisher(keys.BATTERY)
    previous = "ok"
    async for batch in readings:
        newest: m.BatteryReading | None = None
        for reading in batch:
            try:
                state = monitor.update(reading.voltage, reading.current, time.monotonic())
            except BadReading as exc:
                node.limited.warning("hw/battery", "hw/battery: %s; reading ignored", exc)
                continue
            newest = reading
            if state != previous:
                report = node.log.info if state == "ok" else node.log.warning
                report("battery %s: %.2f V", state, monitor.voltage)
                previous = state
            if monitor.shutdown_due:
                shutdown.start("critical battery")
        if newest is not None:  # the state after the newest good reading, with its stamp
            assert monitor.voltage is not None
            battery.put(m.Battery(stamp=newest.stamp, voltage=round(monitor.voltage, 4),
                                  current=round(monitor.current, 4), state=monitor.state))
        if monitor.silent_while_low(time.monotonic(), power.silent_s):  # the board gave up
            shutdown.start("battery readings stopped while low")


SHUTDOWN_BUTTON = 10
"""`Buttons.button` of the shutdown button."""


async def watch_lines(lines: Lines, power: Power, shutdown: Shutdown,
                      buttons: Callable[[m.Buttons], None] | None = None) -> None:
    """Shutdown button (held button_hold_s) and board request line (held request_hold_s).

    ``buttons``: called with each debounced press and release of the shutdown button
    (published on ``io/buttons``, so programs can use it as a button too)."""
    detectors = {
        power.button_line: (HoldDetector(power.button_hold_s, power.debounce_s), "shutdown button"),
        power.request_line: (HoldDetector(power.request_hold_s, power.debounce_s), "board request"),
    }

    edge = asyncio.Event()

    async def feed() -> None:
        async for line, level, t in lines.edges():
            detectors[line][0].edge(level, t)
            edge.set()

    async def poll() -> None:
        # Every half debounce period while a line bounces or is held (it bounds the reaction
        # delay); between presses nothing runs until the next edge.
        while True:
            edge.clear()
            if all(detector.idle for detector, _ in detectors.values()):
                await edge.wait()
            await asyncio.sleep(power.debounce_s / 2)
            now = lines.clock()
            for detector, reason in detectors.values():
                if detector.poll(now):
                    shutdown.start(reason)
            level = detectors[power.button_line][0].settled_change(now)
            if level is not None and buttons is not None:
                pressed = level == 0
                buttons(m.Buttons(stamp=time.time_ns(), button=SHUTDOWN_BUTTON, presses=int(pressed),
                                  event="press" if pressed else "release"))

    async def refresh() -> None:
        while True:
            await asyncio.sleep(1.0)
            lines.refresh()

    async with asyncio.TaskGroup() as tasks:
        tasks.create_task(feed())
        tasks.create_task(poll())
        tasks.create_task(refresh())


async def main(config: RobotConfig) -> None:
    async with Node("power", config) as node:
        readings = battery_readings(node, config.power)
        lines = open_lines(node, config.power)
        try:
            shutdown = Shutdown(node, config.power, lines)
            node.queryable(keys.SHUTDOWN_REQUEST, shutdown.request)
            # Listen first, then raise the acknowledge line ("daemon alive"): whoever
            # sees it high can count on us hearing them.
            lines.drive(config.power.ack_line, 1)
            async with asyncio.TaskGroup() as tasks:
                tasks.create_task(watch_battery(node, config.power, readings, shutdown))
                tasks.create_task(watch_lines(lines, config.power, shutdown,
                                              node.publisher(keys.BUTTONS).put))
        finally:
            lines.close()


if __name__ == "__main__":
    run(main)
