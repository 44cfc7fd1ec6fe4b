"""power and oled end to end with the real simulator and hwbridge processes.

Nothing is played by the test here: the simulated PenguinPi's battery drains
(``sim/control``), its firmware reacts as the real one does, hwbridge reads it
and stops the wheels on ``cmd/halt``, and the simulator sees the acknowledge
line GPIO11 fall.
"""

from __future__ import annotations

import asyncio
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from conftest import Robot, wait_for
from test_power_service import screen

from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m


def config(marker: Path) -> str:
    command = [sys.executable, "-c",
               "import os, sys, time; p = sys.argv[1]; open(p + '.tmp', 'w').write(str(time.time_ns()));"
               " os.replace(p + '.tmp', p)", str(marker)]
    return (f"[power]\npoweroff_command = {json.dumps(command)}\nack_delay_s = 0.1\n"
            "silent_s = 2.0\n")


class Watch:
    """Records the bus traffic the test checks, with arrival order."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.battery: list[m.Battery] = []
        self.notices: list[m.ShutdownNotice] = []
        self.acks: list[m.GpioLevel] = []
        self.frames: list[np.ndarray] = []
        self.logs: list[m.Log] = []
        self._tasks = [asyncio.create_task(self._collect(t)) for t in
                       (keys.BATTERY, keys.SHUTDOWN, keys.SIM_GPIO, keys.OLED_FRAME, keys.LOG)]

    async def _collect(self, topic: keys.Topic) -> None:
        async for msg in self.node.subscribe(topic, latest=False, maxsize=4096):
            if isinstance(msg, m.Battery):
                self.battery.append(msg)
            elif isinstance(msg, m.ShutdownNotice):
                self.notices.append(msg)
            elif isinstance(msg, m.GpioLevel) and msg.line == 11:
                self.acks.append(msg)
            elif isinstance(msg, m.OledFrame):
                self.frames.append(screen(msg))
            elif isinstance(msg, m.Log):
                self.logs.append(msg)

    def power_said(self, text: str) -> m.Log | None:
        return next((lg for lg in self.logs if lg.service == "power" and text in lg.text), None)

    async def sim(self, **request: Any) -> m.SimState:
        return await self.node.query(keys.SIM_CONTROL, m.SimControl(**request), timeout=15)

    async def drive(self, speed: float) -> None:
        """Keep commanding both wheels (the deadman stops them otherwise)."""
        pub = self.node.publisher(keys.WHEELS_CMD)
        while True:
            pub.put(m.WheelSpeeds(left=speed, right=speed))
            await asyncio.sleep(0.1)

    def close(self) -> None:
        for task in self._tasks:
            task.cancel()


async def start(robot: Robot, watch: Watch) -> list[Any]:
    procs = [robot.start(name) for name in ("sim", "hwbridge", "power", "oled")]
    await wait_for(lambda: watch.battery and watch.acks and watch.frames, timeout=30)
    return procs


async def test_button_while_driving_stops_the_wheels_before_power_off(make_robot: Any,
                                                                      tmp_path: Path) -> None:
    marker = tmp_path / "poweroff"
    robot: Robot = make_robot(config(marker))
    async with robot.node() as node:
        watch = Watch(node)
        procs = await start(robot, watch)
        driving = asyncio.create_task(watch.drive(0.2))
        state = await watch.sim()
        loop = asyncio.get_running_loop()
        deadline = loop.time() + 30  # a few seconds idle; CI's loaded machine starts four processes slower
        while not (state.speed_left > 0.1 and state.gpio_ack == 1) and loop.time() < deadline:
            await asyncio.sleep(0.1)  # the wheels get up to speed; the board hears "daemon alive"
            state = await watch.sim()
        assert state.speed_left > 0.1 and state.gpio_ack == 1, state  # power's "daemon alive"

        await watch.sim(action="press_button", button=10, seconds=0.7)
        await wait_for(lambda: watch.notices, timeout=10)
        # The program drives on for a while: power's halt may be released by its commands
        # (hwbridge refuses it then) and power asks again until one holds.
        await asyncio.sleep(0.5)
        driving.cancel()
        assert watch.notices[0].reason == "shutdown button"
        await wait_for(marker.exists, timeout=15)
        poweroff = int(marker.read_text())

        confirmed = watch.power_said("hwbridge confirmed the wheels stopped")
        assert confirmed is not None, [lg.text for lg in watch.logs if lg.service == "power"]
        ack_low = next(a for a in watch.acks if a.level == 0)
        assert watch.notices[0].stamp < confirmed.stamp < ack_low.stamp < poweroff
        t0 = watch.notices[0].stamp
        print(f"notice -> wheels confirmed {(confirmed.stamp - t0) / 1e6:.0f} ms -> ack low "
              f"{(ack_low.stamp - t0) / 1e6:.0f} ms -> power-off {(poweroff - t0) / 1e6:.0f} ms")
        state = await watch.sim()
        assert state.gpio_ack == 0  # the simulated board saw the Pi go
        assert abs(state.speed_left) < 0.01 and abs(state.speed_right) < 0.01
        power, oled = procs[2:]
        assert power.stop() == 0 and oled.stop() == 0  # sim and hwbridge: the fixture stops them
        watch.close()


async def test_battery_drain_warns_inverts_and_shuts_down(make_robot: Any, tmp_path: Path) -> None:
    marker = tmp_path / "poweroff"
    robot: Robot = make_robot(config(marker))
    async with robot.node() as node:
        watch = Watch(node)
        procs = await start(robot, watch)
        node.publisher(keys.OLED_SCREEN).put(m.OledScreen(index=2))
        assert watch.battery[-1].state == "ok"

        await watch.sim(action="set_battery", volts=6.85)
        await wait_for(lambda: watch.battery[-1].state == "low", timeout=15)
        await wait_for(lambda: watch.power_said("battery low"), timeout=15)  # the log line comes on its own key
        # The display inverts: the title bar's right corner goes dark.
        await wait_for(lambda: not watch.frames[-1][0:8, 126:128].any(), timeout=15)

        # Below 6.5 V the PenguinPi firmware halts itself (and its readings): power
        # shuts down either on critical readings or on their silence, whichever first.
        await watch.sim(action="set_battery", volts=6.2)
        await wait_for(lambda: watch.notices, timeout=20)
        assert watch.notices[0].reason in ("critical battery", "battery readings stopped while low")
        print("shutdown reason:", watch.notices[0].reason)
        await wait_for(marker.exists, timeout=15)
        ack_low = next(a for a in watch.acks if a.level == 0)
        assert watch.notices[0].stamp < ack_low.stamp < int(marker.read_text())
        assert (await watch.sim()).gpio_ack == 0
        power, oled = procs[2:]
        assert power.stop() == 0 and oled.stop() == 0  # sim and hwbridge: the fixture stops them
        watch.close()
