"""hwbridge against the simulated PenguinPi firmware on a pseudo-terminal (real pyserial)."""

from __future__ import annotations

import asyncio
import signal

import pytest
from conftest import wait_for
from test_hwbridge_helpers import (
    deadman_delay,
    driving,
    measured_forward_speed,
    sim_state,
    start_stack,
)

from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.wire import penguinpi as ppi

pytestmark = pytest.mark.slow


async def test_twist_drives_deadman_stops_and_sigterm_sends_all_stop(robot) -> None:
    async with robot.node() as node:
        _sim, hw = await start_stack(robot, node)
        loops = node.subscribe(keys.LOOP)
        wheels = node.subscribe(keys.WHEELS, latest=False, maxsize=10_000)
        async with driving(node, v=0.15) as sent:
            await asyncio.sleep(2.0)                     # ramp, then the firmware's PI settles
            speed = await measured_forward_speed(node, 1.5)
            stats = await anext(loops)
        # The firmware alone can only hold multiples of 50 counts/s (0.133 or 0.160 m/s here);
        # hwbridge dithers the demand between them so the average is right.
        assert speed == pytest.approx(0.15, rel=0.05), hw.output
        assert stats.board == "penguinpi"
        # 200 Hz asked, never more; how close it gets depends on load (bench/ measures it).
        assert 100 <= stats.link_rate <= 205, stats
        assert stats.rate == pytest.approx(1000, rel=0.2)

        # Deadman: 0.5 s (+ one cycle, + bus delivery) after the last command. hw/wheels is
        # stamped with its encoder sample, which is up to one exchange (5 ms) older.
        delay = await asyncio.wait_for(deadman_delay(wheels, sent["last_wall_ns"]), 3.0)
        assert 0.5 - 0.005 <= delay <= 0.5 + 0.001 + 0.1, f"deadman fired after {delay:.3f} s"
        # Demands are 0 from then on; the firmware's own PI brakes the wheels to rest.
        for _ in range(100):
            state = await sim_state(node)
            if abs(state.speed_left) < 0.002 and abs(state.speed_right) < 0.002:
                break
            await asyncio.sleep(0.02)
        else:
            raise AssertionError(f"wheels still turning after the deadman: {state}")

        async with driving(node, v=0.15, rate_hz=50):
            await asyncio.sleep(1.0)
            assert hw.stop(signal.SIGTERM) == 0
            after = await sim_state(node)
        # The last datagram the firmware took is MULTI_ALL_STOP, although twists kept coming.
        assert after.last_frame == ppi.encode_frame(ppi.Address.AD_MULTI,
                                                    ppi.MultiOp.MULTI_ALL_STOP)


async def test_noise_on_the_line_is_counted_and_survived(robot) -> None:
    async with robot.node() as node:
        _sim, hw = await start_stack(robot, node)
        wheels = node.subscribe(keys.WHEELS)
        loops = node.subscribe(keys.LOOP)
        async with driving(node, v=0.1):
            await asyncio.sleep(1.0)
            clean = await anext(loops)
            # Garbage and corrupted frames both ways, between good ones.
            await sim_state(node, "inject_noise", probability=0.02, direction="tx")
            await sim_state(node, "inject_noise", probability=0.02, direction="rx")
            await sim_state(node, "drop_bytes", count=3, direction="tx")
            await asyncio.sleep(3.0)
            await sim_state(node, "inject_noise", probability=0.0, direction="tx")
            await sim_state(node, "inject_noise", probability=0.0, direction="rx")
            noisy = await anext(loops)
            assert hw.alive(), hw.output
            # Each kind is counted: replies with flipped bits fail their CRC, requests the
            # firmware rejected (ERR: lines) or never answered time out.
            assert noisy.crc_errors > clean.crc_errors, noisy
            assert noisy.timeouts + noisy.board_errors > clean.timeouts + clean.board_errors
            assert noisy.link_errors > clean.link_errors
            # Clean line again: exchanges flow again (the exact resync is in test_hwbridge_backends).
            await asyncio.sleep(1.2)
            await anext(loops)
            recovered = await anext(loops)
            before = await anext(wheels)
            await asyncio.sleep(0.3)
            after = await anext(wheels)
        assert recovered.link_rate >= 100, recovered
        assert after.ticks_left > before.ticks_left  # encoders still flow
        assert hw.alive()


async def test_battery_buttons_dip_and_board_text(robot) -> None:
    async with robot.node() as node:
        battery = node.subscribe(keys.HW_BATTERY)
        buttons = node.subscribe(keys.BUTTONS, latest=False)
        dips = node.subscribe(keys.DIP, latest=False)
        logs = node.subscribe(keys.LOG, latest=False, maxsize=1000)
        await start_stack(robot, node)
        reading = await asyncio.wait_for(anext(battery), 5.0)
        assert 6.0 < reading.voltage < 9.0 and reading.current > 0
        await sim_state(node, "set_battery", volts=7.2)
        await asyncio.sleep(1.0)
        first = await asyncio.wait_for(anext(dips), 5.0)
        await sim_state(node, "set_dip", dip=0b1011)
        await sim_state(node, "press_button", button=3, seconds=0.05)
        press = await asyncio.wait_for(anext(buttons), 5.0)
        assert press.button == 3 and press.presses == 1
        changed = await asyncio.wait_for(anext(dips), 5.0)
        while changed.value == first.value:  # the same value again, once a second, for late subscribers
            changed = await asyncio.wait_for(anext(dips), 5.0)
        assert (first.value, changed.value) == (0b0001, 0b1011)
        # A text line from the bus reaches the firmware's user screen; a bad LED is refused.
        node.publisher(keys.BOARD_TEXT).put(m.OledText(text="hello\n"))
        node.publisher(keys.LEDS).put(m.Led(led=9))
        seen: list[str] = []

        async def refused() -> None:
            async for line in logs:
                seen.append(line.text)
                if "io/leds: led must be 1..4, got 9" in line.text:
                    return

        await asyncio.wait_for(refused(), 5.0)


async def test_board_link_lost_is_reported_and_retried(make_robot) -> None:
    robot = make_robot()
    async with robot.node() as node:
        logs = node.subscribe(keys.LOG, latest=False, maxsize=1000)
        sim, hw = await start_stack(robot, node)
        sim.stop()                                   # the pseudo-terminal goes away
        texts: list[str] = []

        async def until(needle: str) -> None:
            async for line in logs:
                texts.append(line.text)
                if needle in line.text:
                    return

        await asyncio.wait_for(until("board link lost"), 10.0)
        assert hw.alive()
        robot.start("sim")                           # the board comes back
        await asyncio.wait_for(until("board link up"), 15.0)
        wheels = node.subscribe(keys.WHEELS)
        await asyncio.wait_for(anext(wheels), 5.0)
        await wait_for(hw.alive)
