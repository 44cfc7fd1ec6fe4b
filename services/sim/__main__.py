"""The simulator process: ``python -m icefloe.services.sim --config X``.

It runs the simulated robot (`Simulator`: world, board model, GPIO lines, a
1 kHz clock) and puts it on the bus:

* ``sim/truth`` (`Truth`): the true pose, at ``sim.truth_rate_hz``.
* ``sim/control`` queryable (`SimControl` -> `SimState`): the test handles.
* ``sim/gpio`` (`GpioLevel`): the simulator publishes every level change of
  the button (GPIO22) and the board's request line (GPIO10), and the current
  levels at start and once a second; it listens there for the acknowledge line
  (GPIO11) that the power service drives.

The board itself is reached as on the real robot, not over the bus: the
PenguinPi on its pseudo-terminal (``board.serial_port``), the icoBoard on its
datagram socket (``board.sim_socket``). SIGINT/SIGTERM stop the clock and close
the socket or pseudo-terminal.
"""

from __future__ import annotations

import asyncio
import sys
import time
from collections.abc import Awaitable, Callable

from icefloe.config import RobotConfig
from icefloe.errors import EXIT_CONFIG, ConfigError, IcefloeError
from icefloe.runtime import Node, run
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.sim.gpio import ACK, BUTTON, REQUEST

from .simulator import Simulator, check_config

GPIO_REFRESH_S = 1.0
"""Period of the full `sim/gpio` refresh, for services that start after us, s."""


GIL_SWITCH_S = 0.0002
"""How long a busy thread may keep the GIL before another gets it, s (Python's default: 5 ms)."""


async def main(config: RobotConfig) -> None:
    check_config(config)  # before anything is created: a real board, a device outside run_dir
    # The board's I/O thread must answer an exchange well inside hwbridge's 1 ms cycle,
    # also while the clock thread or a Zenoh callback is busy in Python.
    sys.setswitchinterval(GIL_SWITCH_S)
    # Zenoh's own thread pools, not the services' single thread: with one, the board models
    # answered late often enough to fail tests/test_hwbridge_icoboard.py about one run in six.
    async with Node("sim", config, one_zenoh_thread=False) as node:
        loop = asyncio.get_running_loop()
        gpio_pub = node.publisher(keys.SIM_GPIO)

        def publish_level(line: int, level: int, stamp: int | None = None) -> None:
            gpio_pub.put(m.GpioLevel(stamp=stamp or time.time_ns(), line=line, level=level))

        def on_gpio(line: int, level: int) -> None:
            # Any thread (the clock's, a handler's): stamp now, publish from the event loop.
            if line != ACK:  # GPIO11 is the power service's to publish
                loop.call_soon_threadsafe(publish_level, line, level, time.time_ns())

        # Answer sim/control before the board's socket or pty appears: a test that
        # waits for that file may ask for a handle right away.
        ready: asyncio.Future[Simulator] = loop.create_future()
        node.queryable(keys.SIM_CONTROL, _control(ready))
        try:
            sim = Simulator(config, on_gpio=on_gpio)
        except (OSError, ValueError, IcefloeError) as exc:  # e.g. the socket's folder is not writable
            node.log.error("cannot start the simulated %s: %s", config.board.kind, exc)
            # a bad world or layout file: starting again cannot help (`icefloe up` does not restart it)
            raise SystemExit(EXIT_CONFIG if isinstance(exc, ConfigError) else 1) from None
        try:
            node.log.info("simulating a %s, %s profile; world seed %d (sim.seed = %d repeats this run)",
                          sim.kind, config.sim.profile, sim.world.seed, sim.world.seed)
            ready.set_result(sim)
            sim.start()
            async with asyncio.TaskGroup() as tasks:
                tasks.create_task(_truth(node, sim))
                tasks.create_task(_gpio_refresh(sim, publish_level))
                tasks.create_task(_ack_line(node, sim))
        finally:
            sim.close()
            node.log.info("simulator stopped after %.1f s simulated (%d steps dropped)",
                          sim.clock.now, sim.clock.dropped)


def _control(ready: asyncio.Future[Simulator]) -> Callable[[m.SimControl], Awaitable[m.SimState]]:
    """The ``sim/control`` handler: one action, then the state (once the simulator is built)."""

    async def handle(request: m.SimControl) -> m.SimState:
        sim = await ready
        return sim.control(request)

    return handle


async def _truth(node: Node, sim: Simulator) -> None:
    """Publish the true pose at ``sim.truth_rate_hz``, on absolute deadlines."""
    pub = node.publisher(keys.TRUTH)
    period = 1.0 / sim.config.sim.truth_rate_hz
    deadline = time.monotonic()
    while True:
        # A model that raised has ended the clock thread. (Not "no step for 2 s": a process stopped
        # with SIGSTOP and continued may run this before the clock thread's next step.)
        if not sim.clock.running:
            raise RuntimeError("the simulation clock stopped (see the traceback above)")
        x, y, theta = sim.world.pose
        v, w = sim.world.velocity
        pub.put(m.Truth(stamp=time.time_ns(), x=x, y=y, theta=theta, sim_time=sim.clock.now,
                        collided=sim.world.collided, collisions=sim.world.collisions, v=v, w=w))
        deadline = max(deadline + period, time.monotonic())
        await asyncio.sleep(deadline - time.monotonic())


async def _gpio_refresh(sim: Simulator, publish_level: Callable[[int, int], None]) -> None:
    """Publish the simulator's lines now and then, so a late subscriber learns their levels."""
    while True:
        levels = sim.gpio.levels()
        for line in (BUTTON, REQUEST):
            publish_level(line, levels[line])
        await asyncio.sleep(GPIO_REFRESH_S)


async def _ack_line(node: Node, sim: Simulator) -> None:
    """GPIO11 as the power service drives it, into the board model."""
    async for sample in node.subscribe(keys.SIM_GPIO, latest=False):
        if sample.line != ACK:
            continue  # our own lines, echoed back
        if sample.level not in (0, 1):
            node.limited.warning("sim/gpio", "sim/gpio: GPIO%d level must be 0 or 1, got %d; ignored",
                                 sample.line, sample.level)
            continue
        sim.gpio.set_ack(sample.level)


if __name__ == "__main__":
    run(main, description="icefloe's simulator: the world, a board model and their handles")
