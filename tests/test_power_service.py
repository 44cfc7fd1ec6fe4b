"""power as a real process: battery discharge (with oled, whose display inverts at low),
the shutdown sequence and its order, the debounced shutdown button, the board
request line, bus requests and bad readings.

The tester plays hwbridge (publishes ``hw/battery``, answers ``cmd/halt``) and the
simulator's GPIO lines (``sim/gpio``), each in this process on a real Zenoh session.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from conftest import Robot, wait_for

from icefloe.errors import BadPayload
from icefloe.runtime import MSGPACK, Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.power.battery import READ_PERIOD_S
from icefloe.services.power.shutdown import HALT_RETRY_S


def screen(frame: m.OledFrame) -> np.ndarray:
    """The pixels of an ``oled/frame`` (1 = lit), unpacked as the contract packs them: 1 bit a
    pixel, row-major, most significant bit first. (What the oled service draws is its own tests'.)"""
    return np.unpackbits(np.frombuffer(frame.pixels, np.uint8)).reshape(frame.height, frame.width)

BUTTON, REQUEST, ACK = 22, 10, 11


def power_toml(marker: Path, **power: object) -> str:
    """[power] settings whose power-off command writes its time (ns) to ``marker``."""
    command = [sys.executable, "-c",
               "import os, sys, time; p = sys.argv[1]; open(p + '.tmp', 'w').write(str(time.time_ns()));"
               " os.replace(p + '.tmp', p)", str(marker)]
    # Silence while low has its own test; elsewhere a loaded machine must not trigger it.
    settings: dict[str, object] = {"ack_delay_s": 0.1, "silent_s": 60.0, **power}
    lines = [f"poweroff_command = {json.dumps(command)}"]
    lines += [f"{k} = {json.dumps(v)}" for k, v in settings.items()]
    return "[power]\n" + "\n".join(lines) + "\n"


class FakeBridge:
    """Plays hwbridge and the simulator's lines; records what the power service says, in order."""

    def __init__(self, node: Node, *, halt_delay: float | None = 0.3, refusals: int = 0) -> None:
        self.node = node
        self.refusals = refusals
        """Refuse this many halts first, as hwbridge does when a newer motion released the stop."""
        self.events: list[tuple[str, int, Any]] = []
        """(what, time ns, message): the notice and the ack line at their sender's stamp, the halt
        query when it arrived here and when it was answered. Same machine, same clock."""
        self.battery: list[m.Battery] = []
        self.notices: list[m.ShutdownNotice] = []
        self.acks: list[m.GpioLevel] = []
        self.logs: list[m.Log] = []
        self._tasks = [asyncio.create_task(self._collect(t)) for t in
                       (keys.BATTERY, keys.SHUTDOWN, keys.SIM_GPIO, keys.LOG)]
        self._hw = node.publisher(keys.HW_BATTERY)
        self._gpio = node.publisher(keys.SIM_GPIO)
        if halt_delay is not None:
            self._halt_delay = halt_delay
            node.queryable(keys.HALT, self._halt)

    async def _collect(self, topic: keys.Topic) -> None:
        async for msg in self.node.subscribe(topic, latest=False, maxsize=1024):
            if isinstance(msg, m.Battery):
                self.battery.append(msg)
            elif isinstance(msg, m.ShutdownNotice):
                self.notices.append(msg)
                self.events.append(("notice", msg.stamp, msg))
            elif isinstance(msg, m.GpioLevel) and msg.line == ACK:
                if self.acks and self.acks[-1].level == msg.level:
                    continue  # power repeats its level every second: keep the changes
                self.acks.append(msg)
                self.events.append((f"ack={msg.level}", msg.stamp, msg))
            elif isinstance(msg, m.Log) and msg.service == "power":
                self.logs.append(msg)

    async def _halt(self, request: m.Stop) -> m.Wheels:
        """Like hwbridge: stop the wheels, answer once they have stopped (here: after a delay)."""
        self.events.append(("halt asked", time.time_ns(), request))
        await asyncio.sleep(self._halt_delay)
        if self.refusals:
            self.refusals -= 1
            self.events.append(("halt refused", time.time_ns(), None))
            raise BadPayload("cmd/halt: a motion command issued after the stop released it before "
                             "the board confirmed it")
        self.events.append(("halt answered", time.time_ns(), None))
        return m.Wheels(stamp=time.time_ns(), ticks_left=0, ticks_right=0, speed_left=0.0,
                        speed_right=0.0)

    def what(self) -> list[str]:
        """What happened, in time order. (Arrival order is not enough: the notice and the
        halt query take different paths through the router and may overtake each other.)"""
        return [what for what, _, _ in sorted(self.events, key=lambda e: e[1])]

    async def reading(self, volts: float) -> m.Battery:
        """Publish one raw reading and wait for power's filtered answer to it."""
        stamp = time.time_ns()
        self._hw.put(m.BatteryReading(stamp=stamp, voltage=volts, current=0.4))
        await wait_for(lambda: any(b.stamp == stamp for b in self.battery), timeout=15)
        return next(b for b in self.battery if b.stamp == stamp)

    async def reading_after_a_flood(self, volts: float) -> m.Battery:
        """`reading`, published again each second until power answers one: Zenoh drops what a
        flood leaves no room for in its queues (puts are best effort), this reading too."""
        stamps: list[int] = []
        for _ in range(15):
            stamps.append(time.time_ns())
            self._hw.put(m.BatteryReading(stamp=stamps[-1], voltage=volts, current=0.4))
            with contextlib.suppress(AssertionError):
                await wait_for(lambda: any(b.stamp in stamps for b in self.battery), timeout=1)
                break
        return next(b for b in self.battery if b.stamp in stamps)

    async def until_ready(self) -> None:
        """Wait until power listens: it drives the acknowledge line high once its lines are set up."""
        await wait_for(lambda: any(a.level == 1 for a in self.acks), timeout=15)

    def line(self, line: int, level: int, stamp: int) -> None:
        self._gpio.put(m.GpioLevel(stamp=stamp, line=line, level=level))

    def close(self) -> None:
        for task in self._tasks:
            task.cancel()


async def test_discharge_warns_then_shuts_down_in_order(make_robot: Any, tmp_path: Path) -> None:
    marker = tmp_path / "poweroff"
    robot: Robot = make_robot(power_toml(marker, pole=0.5, critical_readings=3))
    async with robot.node() as node:
        tester = FakeBridge(node)
        frames: list[np.ndarray] = []

        async def watch_screen() -> None:
            async for f in node.subscribe(keys.OLED_FRAME, latest=False):
                frames.append(screen(f))

        screen_task = asyncio.create_task(watch_screen())
        power = robot.start("power")
        oled = robot.start("oled")
        await tester.until_ready()
        await wait_for(lambda: frames, timeout=15)
        node.publisher(keys.OLED_SCREEN).put(m.OledScreen(index=2))  # the battery screen

        def inverted() -> bool:  # the title bar's right corner is lit unless inverted
            return not frames[-1][0:8, 126:128].any()

        states = []
        volts = 7.6
        while not tester.notices and volts > 5.0:
            states.append((await tester.reading(volts)).state)
            if states[-1] == "ok":
                await wait_for(lambda: not inverted())
            if states[-1] == "low" and states.count("low") == 1:
                await wait_for(inverted)  # the display turns at the first low reading
            volts -= 0.05
        await wait_for(marker.exists, timeout=10)
        poweroff = int(marker.read_text())

        # ok, then low (with a warning), then critical, in that order.
        assert states[0] == "ok" and states[-1] == "critical"
        assert states == sorted(states, key=["ok", "low", "critical"].index)
        assert "low" in states
        assert any(lg.level == "warning" and "battery low" in lg.text for lg in tester.logs)
        # The notice came only after three critical readings in a row.
        assert states[-3:] == ["critical"] * 3 and states.count("critical") == 3
        assert tester.notices[0].reason == "critical battery"
        # Strict order: notice -> halt asked -> wheels stopped -> ack line low -> power off.
        assert tester.what() == ["ack=1", "notice", "halt asked", "halt answered", "ack=0"]
        stamps = {what: t for what, t, _ in tester.events}
        assert tester.notices[0].stamp <= stamps["halt asked"]
        assert stamps["halt answered"] <= stamps["ack=0"] <= poweroff
        assert inverted()
        assert power.stop() == 0 and oled.stop() == 0
        screen_task.cancel()
        tester.close()


async def test_one_noisy_sample_below_critical_does_not_shut_down(make_robot: Any,
                                                                   tmp_path: Path) -> None:
    marker = tmp_path / "poweroff"
    robot: Robot = make_robot(power_toml(marker, pole=0.0, critical_readings=3))
    async with robot.node() as node:
        tester = FakeBridge(node)
        power = robot.start("power")
        await tester.until_ready()
        states = [(await tester.reading(v)).state for v in (7.4, 6.0, 7.4, 6.1, 6.2, 7.3, 5.9, 7.4)]
        assert states.count("critical") == 4  # seen and reported, never three in a row
        await asyncio.sleep(0.5)  # let anything late arrive
        assert tester.notices == [] and not marker.exists()
        assert [a.level for a in tester.acks] == [1]
        assert power.stop() == 0
        tester.close()


async def test_readings_that_stop_while_low_shut_down(make_robot: Any, tmp_path: Path) -> None:
    marker = tmp_path / "poweroff"
    robot: Robot = make_robot(power_toml(marker, pole=0.0, silent_s=1.0))
    async with robot.node() as node:
        tester = FakeBridge(node)
        power = robot.start("power")
        await tester.until_ready()
        assert (await tester.reading(7.4)).state == "ok"
        await asyncio.sleep(1.5)  # silence while ok: hwbridge may be restarting, no shutdown
        assert tester.notices == []
        last = time.time_ns()  # before the reading: the service took it later (on a busy machine, much later)
        assert (await tester.reading(6.8)).state == "low"
        await wait_for(lambda: tester.notices, timeout=15)  # like a PenguinPi that halted itself
        assert tester.notices[0].reason == "battery readings stopped while low"
        assert tester.notices[0].stamp - last >= 1_000_000_000
        await wait_for(marker.exists, timeout=10)
        assert power.stop() == 0
        tester.close()


async def test_bouncy_button_is_one_press_and_short_presses_are_ignored(make_robot: Any,
                                                                        tmp_path: Path) -> None:
    marker = tmp_path / "poweroff"
    robot: Robot = make_robot(power_toml(marker))
    async with robot.node() as node:
        tester = FakeBridge(node)
        power = robot.start("power")
        await tester.until_ready()
        ms = 1_000_000
        t0 = time.time_ns()
        for i, level in enumerate((0, 1, 0, 1)):  # a burst that ends released
            tester.line(BUTTON, level, t0 + 4 * i * ms)
        # A 0.2 s press: too short. Both edges go out at once, with their times in the
        # stamps, so a slow bus on a loaded machine cannot stretch the press.
        tester.line(BUTTON, 0, t0 + 100 * ms)
        tester.line(BUTTON, 1, t0 + 300 * ms)
        await asyncio.sleep(1.0)
        assert tester.notices == []

        t1 = time.time_ns()
        for i, level in enumerate((0, 1, 0, 1, 0)):  # a bouncy press, then held
            tester.line(BUTTON, level, t1 + 3 * i * ms)
        await wait_for(lambda: tester.notices, timeout=15)
        assert tester.notices[0].reason == "shutdown button"
        # Held for at least 0.5 s after the last bounce.
        assert tester.notices[0].stamp - (t1 + 12 * ms) >= 500 * ms
        await wait_for(marker.exists, timeout=10)
        assert len(tester.notices) == 1
        assert tester.what() == ["ack=1", "notice", "halt asked", "halt answered", "ack=0"]
        assert power.stop() == 0
        tester.close()


async def test_board_request_line_must_stay_low(make_robot: Any, tmp_path: Path) -> None:
    marker = tmp_path / "poweroff"
    robot: Robot = make_robot(power_toml(marker, request_hold_s=1.0))
    async with robot.node() as node:
        tester = FakeBridge(node)
        power = robot.start("power")
        await tester.until_ready()
        t0 = time.time_ns()
        tester.line(REQUEST, 0, t0)  # like an SPI reflash toggling GPIO10: let go too soon
        tester.line(REQUEST, 1, t0 + 500_000_000)
        await asyncio.sleep(1.5)
        assert tester.notices == []
        t1 = time.time_ns()
        tester.line(REQUEST, 0, t1)
        await wait_for(lambda: tester.notices, timeout=15)
        assert tester.notices[0].reason == "board request"
        assert tester.notices[0].stamp - t1 >= 1_000_000_000
        await wait_for(marker.exists, timeout=10)
        assert power.stop() == 0
        tester.close()


async def test_bus_request_without_hwbridge_times_out_and_still_powers_off(make_robot: Any,
                                                                           tmp_path: Path) -> None:
    marker = tmp_path / "poweroff"
    robot: Robot = make_robot(power_toml(marker, halt_timeout_s=0.5))
    async with robot.node() as node:
        tester = FakeBridge(node, halt_delay=None)  # nobody answers cmd/halt
        power = robot.start("power")
        await tester.until_ready()
        notice = await node.query(keys.SHUTDOWN_REQUEST,
                                  m.ShutdownRequest(reason="lab\x1b[2J closes\n"), timeout=15)
        assert notice.reason == "lab[2J closes"  # control characters removed
        await wait_for(marker.exists, timeout=10)
        assert any(lg.level == "error" and "no wheel-stop confirmation" in lg.text
                   for lg in tester.logs)
        assert tester.what() == ["ack=1", "notice", "ack=0"]
        # A second request does not start a second shutdown: it gets the first notice.
        again = await node.query(keys.SHUTDOWN_REQUEST, m.ShutdownRequest(), timeout=15)
        assert again == notice
        assert power.stop() == 0
        tester.close()


async def test_a_halt_refused_while_a_program_drives_is_asked_again(make_robot: Any,
                                                                    tmp_path: Path) -> None:
    """hwbridge refuses a halt whose stop a newer motion command released (a program still
    driving as the shutdown begins): power asks again while ``halt_timeout_s`` lasts, and powers
    off after hwbridge confirms; refused to the end, it powers off anyway and says why."""
    for refusals, confirmed in ((2, True), (1000, False)):
        marker = tmp_path / f"poweroff-{refusals}"
        robot: Robot = make_robot(power_toml(marker, halt_timeout_s=2.0))
        async with robot.node() as node:
            tester = FakeBridge(node, halt_delay=0.05, refusals=refusals)
            power = robot.start("power")
            await tester.until_ready()
            await node.query(keys.SHUTDOWN_REQUEST, m.ShutdownRequest(reason="lab closes"), timeout=15)
            await wait_for(marker.exists, timeout=15)
            what = tester.what()
            asked = what.count("halt asked")
            if confirmed:
                assert what == ["ack=1", "notice"] + ["halt asked", "halt refused"] * 2 + [
                    "halt asked", "halt answered", "ack=0"], what
            else:  # for 2 s, a pause after each: not one query after another as fast as they come
                assert 3 <= asked <= 2.0 / HALT_RETRY_S + 1 and what[-1] == "ack=0", what
                assert any(lg.level == "error" and "no wheel-stop confirmation" in lg.text
                           for lg in tester.logs)
            said = [lg.text for lg in tester.logs]
            assert any("hwbridge confirmed the wheels stopped" in t for t in said) == confirmed, said
            assert sum("cmd/halt refused" in t for t in said) <= 3 * 2, said  # three a second
            print(f"{refusals} refusals: {asked} halts asked, "
                  f"{'confirmed' if confirmed else 'not confirmed'}")
            assert power.stop() == 0
            tester.close()


async def test_bad_battery_readings_are_logged_and_ignored(make_robot: Any,
                                                                 tmp_path: Path) -> None:
    robot: Robot = make_robot(power_toml(tmp_path / "poweroff"))
    async with robot.node() as node:
        tester = FakeBridge(node)
        power = robot.start("power")
        await tester.until_ready()
        await tester.reading(7.4)
        node.publisher(keys.HW_BATTERY).put(m.BatteryReading(stamp=1, voltage=-3.0, current=0.0))
        await wait_for(lambda: any("outside 0..30 V" in lg.text for lg in tester.logs), timeout=15)
        # A map key that is not UTF-8: not valid MessagePack, in the runtime's words.
        node.session.put(node.key(keys.HW_BATTERY), b"\x81\xa2\xff\xfe\x01", encoding=MSGPACK)
        bad = f"{node.key(keys.HW_BATTERY)}: not valid MessagePack"
        await wait_for(lambda: any(bad in lg.text for lg in tester.logs), timeout=15)
        assert (await tester.reading(7.3)).state == "ok"  # still running, still filtering
        assert all(b.stamp != 1 for b in tester.battery)
        assert power.stop() == 0
        tester.close()


async def test_a_flood_of_readings_costs_a_bounded_batch(make_robot: Any, tmp_path: Path) -> None:
    """hw/battery at thousands a second: power takes at most READ_BACKLOG readings a batch (the
    oldest go), publishes power/battery once a batch whatever came, and answers the next reading."""
    robot: Robot = make_robot(power_toml(tmp_path / "poweroff"))
    async with robot.node() as node:
        tester = FakeBridge(node)
        power = robot.start("power")
        await tester.until_ready()
        t0 = time.monotonic()
        flood = node.publisher(keys.HW_BATTERY)
        for i in range(5000):
            flood.put(m.BatteryReading(stamp=i + 1, voltage=7.4 if i % 7 else 99.0, current=0.1))
        assert (await tester.reading_after_a_flood(7.3)).state == "ok"
        wall = time.monotonic() - t0
        assert len(tester.battery) <= wall / READ_PERIOD_S + 3  # once a batch, not once a reading
        await wait_for(lambda: any("outside 0..30 V" in lg.text for lg in tester.logs), timeout=15)
        assert sum("outside 0..30 V" in lg.text for lg in tester.logs) < 50  # rate-limited, not 700 lines
        assert power.alive() and power.stop() == 0
        tester.close()
