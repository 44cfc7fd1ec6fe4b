"""The simulator process: real processes, a real Zenoh router, the board reached as hwbridge would."""

from __future__ import annotations

import asyncio
import signal
import socket
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from conftest import Robot

from icefloe.config import parse
from icefloe.errors import EXIT_CONFIG, BadPayload, BoardMismatch, NotReachable
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.sim.simulator import Simulator
from icefloe.wire.icoboard import Op, Wire, duty_to_raw


async def read(node: Node, **action: Any) -> m.SimState:
    return await node.query(keys.SIM_CONTROL, m.SimControl(**action), timeout=5.0)


async def wait_running(node: Node) -> m.SimState:
    """The sim process answers once it is up (queries before that find nobody)."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + 30.0  # a generous start-up: the test machine is shared
    while True:
        try:
            return await read(node)
        except NotReachable:
            if loop.time() > deadline:
                raise
            await asyncio.sleep(0.1)


async def test_icoboard_sim_process(make_robot: Callable[..., Robot]) -> None:
    robot = make_robot('[board]\nkind = "icoboard"\nprotocol = 2\n\n[sim]\nseed = 42\n')
    proc = robot.start("sim")
    async with robot.node("tester") as node:
        truths = node.subscribe(keys.TRUTH)
        gpio = node.subscribe(keys.SIM_GPIO, latest=False)
        state = await wait_running(node)
        assert state.board == "icoboard-v2" and state.seed == 42
        assert "world seed 42" in proc.output
        first = await asyncio.wait_for(anext(truths), 5.0)
        assert (first.x, first.y, first.theta) == (0.0, 0.0, 0.0)

        # Drive the board through its socket, as hwbridge does, and watch the truth move.
        wire = Wire.for_board(robot.config.board)
        host = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        host.bind("")
        host.settimeout(2.0)
        host.connect(robot.config.board.sim_socket)
        try:
            host.send(wire.request(Op.START, seq=0))
            wire.check_start(wire.parse_reply(Op.START, host.recv(64)))
            half = duty_to_raw(0.5)
            for seq in range(1, 40):
                host.send(wire.request(Op.TRANSMIT, seq=seq, duties=[half, half]))
                wire.parse_reply(Op.TRANSMIT, host.recv(64))
                await asyncio.sleep(0.01)
            state = await read(node)
            # The board took our last frame. (Its duty may already be back to 0 if this
            # process stalled for 50 ms on a busy machine: the watchdog is allowed to act.)
            assert wire.parse_request(state.last_frame).duties == (half, half)
            assert state.duty_left in (pytest.approx(0.5, abs=1e-4), 0.0)
            # The host goes silent: the board's watchdog stops the wheels.
            state = await wait_for_state(node, lambda s: s.watchdog_trips >= 1)
            assert (state.duty_left, state.duty_right) == (0.0, 0.0)
            # Injected noise: the next two frames arrive corrupt and are counted, not used.
            await read(node, action="inject_noise", count=2)
            for seq in range(40, 42):
                host.send(wire.request(Op.TRANSMIT, seq=seq, duties=[half, half]))
                host.recv(64)
            state = await read(node)
            assert state.bad_frames == 2 and state.duty_left == 0.0
            # A board with other peripherals than the config says: the host refuses it.
            await read(node, action="force_descriptor", sensors=3, actuators=2)
            host.send(wire.request(Op.START, seq=42))
            with pytest.raises(BoardMismatch, match="sensors M = 3"):
                wire.check_start(wire.parse_reply(Op.START, host.recv(64)))
        finally:
            host.close()
        latest = await asyncio.wait_for(anext(truths), 5.0)
        assert latest.x > 0.01 and abs(latest.y) < 1e-3  # drove straight ahead

        # The shutdown button shows on sim/gpio, pressed and then released.
        state = await read(node, action="press_button", button=10, seconds=0.3)
        assert state.gpio_button == 0

        async def level_of_22(want: int) -> None:
            async for sample in gpio:
                if sample.line == 22 and sample.level == want:
                    return

        await asyncio.wait_for(level_of_22(0), 5.0)
        await asyncio.wait_for(level_of_22(1), 5.0)  # released by itself after 0.3 s

        # The power service drives the acknowledge line on sim/gpio; the board side sees it.
        node.publisher(keys.SIM_GPIO).put(m.GpioLevel(stamp=1, line=11, level=1))
        await wait_for_state(node, lambda s: s.gpio_ack == 1)

        # Bad requests get one clear error and the simulator keeps running.
        with pytest.raises(BadPayload, match=r"set_battery.*\[0, 20\] V, got 50"):
            await read(node, action="set_battery", volts=50.0)
        with pytest.raises(BadPayload, match="only the PenguinPi has DIP"):
            await read(node, action="set_dip", dip=3)
        state = await read(node, action="set_battery", volts=6.8)
        assert state.battery_voltage < 6.8
    assert proc.stop(signal.SIGINT) == 0
    assert not Path(robot.config.board.sim_socket).exists()
    assert "Traceback" not in proc.output


async def wait_for_state(node: Node, predicate: Callable[[m.SimState], bool],
                         timeout: float = 5.0) -> m.SimState:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        state = await read(node)
        if predicate(state):
            return state
        if loop.time() > deadline:
            raise AssertionError(f"state never matched: {state}")
        await asyncio.sleep(0.05)


async def test_penguinpi_sim_process(robot: Robot) -> None:
    proc = robot.start("sim")
    async with robot.node("tester") as node:
        truths = node.subscribe(keys.TRUTH)
        state = await wait_running(node)
        assert state.board == "penguinpi"
        await asyncio.wait_for(anext(truths), 5.0)
        assert Path(robot.config.board.serial_port).exists()  # the pseudo-terminal
        state = await read(node, action="stall", wheel="right", on=True)
        state = await read(node, action="set_dip", dip=5)
        with pytest.raises(BadPayload, match="icoBoard has a START descriptor"):
            await read(node, action="force_descriptor", sensors=3, actuators=2)
        state = await read(node, action="set_gpio", line=10, level=0)
        assert state.gpio_request == 0
    assert proc.stop(signal.SIGTERM) == 0
    assert not Path(robot.config.board.serial_port).exists()  # the pty's link is gone
    assert "Traceback" not in proc.output


@pytest.mark.parametrize(("board", "key"), [('kind = "icoboard"\nsim_socket = "{dir}/ico.sock"', "sim_socket"),
                                          ('serial_port = "{dir}/ttyUSB0"', "serial_port")])
def test_a_device_path_outside_the_run_dir_is_refused(make_robot: Callable[..., Robot], tmp_path: Path,
                                                      board: str, key: str) -> None:
    elsewhere = tmp_path / "not-run-dir" / "dev"
    robot = make_robot("[board]\n" + board.format(dir=elsewhere) + "\n")
    proc = robot.start("sim")
    assert proc.popen.wait(20) == EXIT_CONFIG
    assert f"board.{key}: {elsewhere}/" in proc.output and "is outside the run directory" in proc.output
    assert "Traceback" not in proc.output
    assert not elsewhere.parent.exists()  # nothing made there, not even the folder


def test_the_simulator_refuses_a_real_board(make_robot: Callable[..., Robot]) -> None:
    robot = make_robot('[board]\nbackend = "hardware"\nserial_port = "/dev/null"\n')
    proc = robot.start("sim")
    assert proc.popen.wait(20) == EXIT_CONFIG
    assert 'board.backend = \'hardware\': the simulator runs only for a simulated board' in proc.output


def test_penguinpi_shutdown_lines_reach_the_firmware(tmp_path: Path) -> None:
    """GPIO10 follows the firmware's PB5; GPIO11 (the Pi's daemon line) reaches its PB7."""
    config = parse({"run_dir": str(tmp_path), "sim": {"seed": 3}, "board": {"serial_port": "{run_dir}/ttyPPI"}})
    sim = Simulator(config)
    try:
        firmware = sim.board.model
        assert sim.gpio.request == 1
        firmware.shutdown_request = True
        assert sim.gpio.request == 0
        firmware.shutdown_request = False
        sim.control(m.SimControl(action="set_gpio", line=11, level=1))  # the daemon is alive
        sim.clock.run(0.05)
        assert firmware.daemon_alive and firmware.shutdown_reason is None
        sim.control(m.SimControl(action="set_gpio", line=11, level=0))  # the Pi shuts down
        sim.clock.run(0.05)
        assert firmware.shutdown_reason == " TURN RaspberryPI OFF SAFELY "
        assert sim.state().duty_left == 0.0
    finally:
        sim.close()
