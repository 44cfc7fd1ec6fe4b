"""The simulated robot in one object: world, board model, GPIO lines, clock, and the handles.

`Simulator` owns no bus: ``__main__`` puts it on Zenoh. Tests can build one
directly. `Simulator.control` runs one `SimControl` action and answers the
`SimState`; a bad action raises `BadPayload` with one clear message and changes
nothing.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path

from icefloe.config import RobotConfig
from icefloe.errors import BadPayload, ConfigError
from icefloe.schemas import messages as m
from icefloe.sim import realism
from icefloe.sim.clock import SimClock
from icefloe.sim.gpio import BUTTON, GpioLines
from icefloe.sim.icoboard import BoardModel, IcoBoardSim
from icefloe.sim.penguinpi import PenguinPiSim
from icefloe.sim.world import World
from icefloe.wire import penguinpi
from icefloe.wire.icoboard import Descriptor
from icefloe.worldmap import load_world

log = logging.getLogger("icefloe.sim")

LED_NUMBERS = ("red", "led2", "led3", "led4")
"""The firmware's name of `Led` number 1..4 (`SimState.leds` bit 0..3)."""


def device_path(config: RobotConfig) -> tuple[str, Path]:
    """The config key and the path of the simulated board's device (pseudo-terminal or socket)."""
    b = config.board
    key, path = ("sim_socket", b.sim_socket) if b.kind == "icoboard" else ("serial_port", b.serial_port)
    return key, Path(path)


def check_config(config: RobotConfig) -> None:
    """Refuse to simulate a real board, or to make a device anywhere but in the run directory
    (a wrong ``serial_port`` must not become a fake ``/dev/ttyUSB0`` that hwbridge drives)."""
    if config.board.backend != "sim":
        raise ConfigError(f"{config.source}: board.backend = {config.board.backend!r}: the simulator runs only "
                          f"for a simulated board (backend = \"sim\")")
    key, path = device_path(config)
    run_dir = config.runtime_dir.resolve()
    if not (path.parent.resolve() / path.name).is_relative_to(run_dir):
        raise ConfigError(f"{config.source}: board.{key}: {path} is outside the run directory {run_dir}; "
                          f"the simulator makes its device only there (\"{{run_dir}}/{path.name}\")")


GATEWARE_CATCH_UP = 5
"""Steps the clock may run back to back to catch up, with the gateware as the board (ms)."""


def _icoboard_model(config: RobotConfig, world: World) -> BoardModel | None:
    """The gateware as the board when the config asks for it (None: the Python model)."""
    if config.sim.icoboard != "gateware":
        return None
    if config.board.protocol != 2:
        raise ConfigError(f"{config.source}: board.protocol: the icoBoard gateware speaks protocol v2 only")
    try:
        from icefloe.sim.icoboard_gateware import GatewareBoardModel
    except ImportError as exc:  # a restart cannot help: ConfigError (exit 78), not a crash
        raise ConfigError(f'{config.source}: sim.icoboard = "gateware" needs the gateware extra ({exc}): '
                          "pip install --require-hashes -r deploy/requirements/gateware.txt") from None
    return GatewareBoardModel(world, config.board, clk_hz=config.sim.gateware_clk_hz, seed=world.seed)


class Simulator:
    """World + board + GPIO lines, stepped by a 1 kHz `SimClock` (started by `start`)."""

    def __init__(self, config: RobotConfig,
                 on_gpio: Callable[[int, int], None] | None = None) -> None:
        """``on_gpio(line, level)``: called on any thread when a line changes level.

        `ConfigError` for a config of a real board, or a device path outside the run directory."""
        check_config(config)
        self.config = config
        sim = config.sim
        wheels = realism.wheels(config)  # the profile's, or [sim.wheels]'s: not what [geometry] believes
        self.world = World(config.geometry, seed=sim.seed, slip=wheels.slip, encoder_noise=wheels.encoder_noise,
                           obstacles=load_world(sim.world).obstacles, wheels=wheels)
        self.world.set_pose(sim.start_x, sim.start_y, sim.start_theta)  # where the robot stands in the lab
        self.board: IcoBoardSim | PenguinPiSim
        if config.board.kind == "icoboard":
            self.board = IcoBoardSim(self.world, config.board, seed=self.world.seed,
                                     model=_icoboard_model(config, self.world))
            self.kind = f"icoboard-v{config.board.protocol}"
            self.gpio = GpioLines(on_change=on_gpio)
            self._lock = self.board.lock
        else:
            self.board = PenguinPiSim(self.world, config.board, seed=self.world.seed)
            self.kind = "penguinpi"
            firmware = self.board.model
            # The firmware drives GPIO10 from its PB5 and reads GPIO11 on its PB7 (facts §3.8).
            self.gpio = GpioLines(request_source=lambda: firmware.shutdown_request,
                                  on_change=on_gpio)
            firmware.daemon_alive_source = lambda: self.gpio.ack == 1
            self._lock = firmware.lock
        # Each simulated millisecond: the world moves, then the board and the lines see it.
        # The gateware's watchdog counts board time: racing through a long backlog of steps
        # with none of the host's frames in between would trip it. On an overloaded machine
        # its simulated time slows down instead (steps dropped), as the world's does.
        gateware = config.board.kind == "icoboard" and config.sim.icoboard == "gateware"
        catch_up = GATEWARE_CATCH_UP if gateware else 100
        self.clock = SimClock(self.world, [self.board, self.gpio], max_catch_up=catch_up)

    def start(self) -> None:
        self.clock.start()

    def close(self) -> None:
        """Stop the clock, then close the board's socket or pseudo-terminal."""
        self.clock.stop()
        self.board.close()

    # ------------------------------------------------------------------ state

    def state(self) -> m.SimState:
        """The true state now."""
        x, y, theta = self.world.pose
        duty = self.world.duty
        speeds = self.world.wheel_speeds
        if isinstance(self.board, IcoBoardSim):  # every frame, and what went wrong
            ico = self.board.model
            last, bad, trips = ico.last_frame, ico.counters.bad_frames, ico.counters.watchdog_trips
            integrators = (0, 0)  # the icoBoard's controller runs in hwbridge
            leds = 0
        else:  # the PenguinPi: its last good datagram, and its error count
            model = self.board.model
            frame = model.last_datagram
            last = penguinpi.encode_frame(frame.address, frame.opcode, frame.payload) if frame else b""
            bad, trips = model.errors, 0
            integrators = (model.left.integral, model.right.integral)
            leds = sum(1 << n for n, name in enumerate(LED_NUMBERS) if model.led_lit(name))
        ticks = self.world.counts()
        return m.SimState(
            stamp=time.time_ns(), sim_time=self.clock.now, seed=self.world.seed,
            board=self.kind, x=x, y=y, theta=theta, duty_left=duty[0], duty_right=duty[1],
            speed_left=speeds[0], speed_right=speeds[1],
            battery_voltage=self.world.battery_voltage, battery_current=self.world.battery_current,
            last_frame=bytes(last), bad_frames=bad, watchdog_trips=trips,
            gpio_button=self.gpio.button, gpio_request=self.gpio.request, gpio_ack=self.gpio.ack,
            peak_duty=self.world.peak_duty, ticks_left=ticks[0], ticks_right=ticks[1],
            integrator_left=integrators[0], integrator_right=integrators[1],
            zero_duty_since=self.world.zero_duty_since, counts_changed=self.world.counts_changed,
            leds=leds, collided=self.world.collided, collisions=self.world.collisions,
            paused=self.clock.paused)

    # ------------------------------------------------------------------ handles

    def control(self, request: m.SimControl) -> m.SimState:
        """Run one action (see `SimControl`) and answer the state after it."""
        action = request.action
        try:
            with self._lock:
                self._apply(request)
        except (ValueError, TypeError) as exc:
            raise BadPayload(f"action {action!r}: {exc}") from None
        if action == "place":
            log.info("sim/control: place at x %.3f m, y %.3f m, theta %.3f rad (the truth jumps; "
                     "the encoders and odometry do not)", request.x, request.y, request.theta)
        elif action != "read":
            log.info("sim/control: %s", action)
        return self.state()

    def _apply(self, r: m.SimControl) -> None:
        model = self.board.model
        if r.action == "read":
            return
        if r.action == "set_battery":
            self.world.set_battery_voltage(r.volts)
        elif r.action == "stall":
            self.world.stall(r.wheel, r.on)
        elif r.action == "set_gpio":
            self.gpio.set(r.line, r.level)
        elif r.action in ("press_button", "hold_button", "release_button"):
            self._button(r)
        elif r.action == "set_dip":
            if self.config.board.kind != "penguinpi":
                raise ValueError("only the PenguinPi has DIP switches")
            model.hat.set_dip(r.dip)
        elif r.action == "inject_noise":
            if self.config.board.kind == "icoboard":  # the next `count` frames, one bit each
                if r.count < 1:
                    raise ValueError(f"count must be >= 1, got {r.count}")
                if r.direction == "rx":
                    model.corrupt(requests=r.count)
                else:
                    model.corrupt(replies=r.count)
            else:  # the serial line: each byte, with `probability`
                model.line.noise(r.probability, r.direction)
        elif r.action == "drop_bytes":
            if self.config.board.kind == "icoboard":
                raise ValueError("the icoBoard link has no bytes to drop (use inject_noise)")
            if r.count < 1:
                raise ValueError(f"count must be >= 1, got {r.count}")
            model.line.drop(r.count, r.direction)
        elif r.action == "mark":
            self.world.mark()
        elif r.action == "place":
            self.world.place(r.x, r.y, r.theta)
        elif r.action == "reset":
            sim = self.config.sim
            self.world.reset((sim.start_x, sim.start_y, sim.start_theta))
        elif r.action in ("pause", "resume"):
            self.clock.paused = r.action == "pause"
        elif r.action == "delay_replies":
            if isinstance(self.board, IcoBoardSim):
                self.board.delay_replies(r.seconds, r.count)
            else:
                model.line.delay(r.seconds, r.count, "tx")
        elif r.action == "force_descriptor":
            if self.config.board.kind != "icoboard":
                raise ValueError("only the icoBoard has a START descriptor")
            if r.sensors < 0 and r.actuators < 0:
                model.forced_descriptor = None
            elif not (0 <= r.sensors <= 255 and 0 <= r.actuators <= 255):
                raise ValueError("sensors and actuators must both be 0..255 (or both -1)")
            else:
                model.forced_descriptor = Descriptor.of(r.sensors, r.actuators)

    def _button(self, r: m.SimControl) -> None:
        if r.button == 10:  # the SDN shutdown button on GPIO22
            if r.action == "press_button":
                self.gpio.hold(r.seconds)
            else:
                self.gpio.set(BUTTON, 0 if r.action == "hold_button" else 1)
            return
        if not 0 <= r.button <= 3 or self.config.board.kind != "penguinpi":
            raise ValueError(f"button must be 10 (shutdown) or 0..3 (the PenguinPi's S1..S4), "
                             f"got {r.button}")
        name, hat = f"S{r.button + 1}", self.board.model.hat
        if r.action == "press_button":
            hat.press(name)
        else:
            hat.hold(name, r.action == "hold_button")
