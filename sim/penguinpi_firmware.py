"""A device model of the PenguinPi firmware (ATmega644PA), faithful on the wire.

It reproduces, from penguinpi-facts.md, what the board does with every byte it
receives and every millisecond that passes; it knows nothing of threads or
pseudo-terminals (``pty_link.py`` and ``penguinpi.py`` add those). Two clocks
drive it, as on the real board:

* `receive` (bytes from the serial line, stamped with the link's clock, s): the
  datagram parser with its ~200 µs inter-byte timeout (facts §1.4);
* `tick` (the 1 ms timer interrupt, simulated seconds): LED countdowns, the
  50 Hz velocity controller, ADC sampling every 11 ms, battery supervision and
  the shutdown handshake (facts §3).

Known firmware defects (facts §8) are reproduced by default; `Defects` switches
each one to the corrected behaviour. The HAT, the OLED state and the user-text
buffer are in ``penguinpi_hat.py``.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable

from icefloe.wire import penguinpi as w

from .penguinpi_datagram import dispatch
from .penguinpi_hat import Hat
from .penguinpi_parts import HW_MA_PER_COUNT, HW_MV_PER_COUNT, Adc, Defects, Motor, clamp, f32, int16
from .pty_link import LineFaults
from .world import World

SERIAL_TIMEOUT_S = 200e-6
"""The parser waits 10 x 20 µs for each further byte of a datagram (facts §1.4)."""
CONTROL_PERIOD_MS = 20
"""Velocity controller period (50 Hz)."""
ADC_PERIOD_MS = 11
"""ADC conversion period (the counter fires when it exceeds 10)."""
LOW_MV = 7000.0
"""Below this smoothed voltage the OLED is inverted (once, never reverted)."""
SHUTDOWN_MV = 6500.0
"""Below this smoothed voltage the board enters its permanent shutdown state."""
LED_NAMES = ("red", "green", "blue", "led2", "led3", "led4")
"""The six LEDs: RGB LED 1's channels (0x31-0x33) and yellow LEDs 2-4 (0x34-0x36)."""


class PenguinPiFirmware:
    """The firmware as a device model. Thread-safe: one lock guards all state.

    ``transmit(data)`` is called with every byte string the board sends (replies
    and text), in order; `PenguinPiSim` connects it to the paced serial link.
    """

    def __init__(self, world: World, *, transmit: Callable[[bytes], None] | None = None,
                 defects: Defects | None = None, dip: int = 0b0001,
                 serial_timeout_s: float | None = SERIAL_TIMEOUT_S,
                 baud: int = 115200) -> None:
        """``dip``: DIP switches at power-on. ``serial_timeout_s``: the inter-byte
        timeout (None = off). ``baud``: line rate, to know when each byte of a chunk came."""
        self.world = world
        self.defects = defects or Defects()
        self.transmit = transmit or (lambda data: None)
        self.serial_timeout_s = serial_timeout_s
        self.byte_time = 10 / baud
        """Seconds per byte on the line (8N1)."""
        self.lock = threading.RLock()
        self.right = Motor()
        self.left = Motor()
        self.leds = [{"state": 0, "count": 0} for _ in LED_NAMES]
        self.volts = Adc(scale=f32(16.018497), hw_per_count=HW_MV_PER_COUNT)
        self.amps = Adc(scale=f32(3.2226562), hw_per_count=HW_MA_PER_COUNT)
        self.hat = Hat(self, dip)
        self.pid_on = True            # 3 at boot; only a HAT interrupt changes it (facts §3.5)
        self.packets_in = 0
        self.packets_out = 0
        self.errors = 0
        self.last_datagram: w.Frame | None = None
        """Last datagram with a good CRC (the OLED's DATAGRAM screen)."""
        self.stop_received = -1.0
        """Link time (s, the link's clock: this machine's monotonic one) at which the last datagram
        arrived that set both wheels' demand to zero while either was driven: a stop's receipt, which
        a test times a stop to (the duty follows at the next control step), or -1 before any."""
        self.stop_received_sim = -1.0
        """The simulated time (``world.time``, s) of that receipt: the duty's zero follows it by the
        firmware's wait for its next control step, on the simulator's clock (which a loaded machine
        delays behind the link's, so the two clocks are not compared)."""
        self.text_sent: deque[str] = deque(maxlen=200)
        """Text lines the board sent (``ERR: ...``, ``DBG: ...``), newest last."""
        self.daemon_alive = False
        """PB7 <- GPIO11: high while the Pi's shutdown daemon runs. Set by the simulator's GPIO."""
        self.daemon_alive_source: Callable[[], bool] | None = None
        """If set, read every tick instead of `daemon_alive` (e.g. the sim's GPIO line)."""
        self._daemon_seen = False
        self.shutdown_reason: str | None = None
        """Set once the board has entered its permanent shutdown state (facts §3.7)."""
        self._next_shutdown_print: float | None = None
        self.shutdown_request = False
        """PB5 -> GPIO10, True while the board pulls the line low ("please shut down")."""
        self._dg = bytearray(w.MAX_LEN + 1)     # the firmware's datagram buffer (stale bytes stay)
        self._state = "idle"                     # idle | len | body
        self._filled = 0
        self._last_rx = 0.0
        self._ms = 0
        self._world_counts = world.counts()
        self.volts.sample(world.battery_voltage * 1000)   # sampled during the ~6 s boot
        self.amps.sample(world.battery_current * 1000)
        self.line: LineFaults | None = None
        """Faults on the serial line (set by `PenguinPiSim`): ``line.drop(3)``, ``line.noise(0.01)``."""

    def start(self) -> None:
        """The end of the boot sequence: the UART is up and the main loop starts (facts §3.13)."""
        with self.lock:
            self.text("DBG: starting main loop")

    # ================================================================== serial input

    def receive(self, data: bytes, now: float) -> None:
        """Bytes that arrived back-to-back on the serial line, the last one at link time ``now`` (s)."""
        if not data:
            return
        with self.lock:
            self.poll(now - (len(data) - 1) * self.byte_time)   # when the first byte came
            self._last_rx = now
            if self.shutdown_reason is not None:
                return                           # the shutdown loop never reads the UART
            for byte in data:
                self._byte(byte)

    def receive_error(self, now: float, message: str = "Bad UART frame") -> None:
        """A byte with a UART error flag (framing error, overrun) arrived (facts §1.4)."""
        with self.lock:
            self.poll(now)
            self._last_rx = now
            if self.shutdown_reason is not None:
                return
            self.error(message, red_ms=250)
            if self._state != "idle":
                self._byte(0x00)                 # inside a frame the firmware takes it as 0x00

    def poll(self, now: float) -> None:
        """Let link time pass: a datagram left incomplete too long ends in ``Serial timeout``."""
        with self.lock:
            timeout = self.serial_timeout_s
            if self._state != "idle" and timeout is not None and now - self._last_rx > timeout:
                self._state = "idle"
                self.error("Serial timeout", red_ms=250)

    def _byte(self, byte: int) -> None:
        if self._state == "idle":
            if byte == w.START:
                self._state = "len"
            elif byte != 0x00:
                self.hat.user_byte(byte)
        elif self._state == "len":
            if byte > w.MAX_LEN:
                self._state = "idle"
                self.error(f"Datagram too long {byte}", red_ms=250)
                return
            self._dg[0] = byte
            self._filled = 1
            self._state = "body"
            if byte <= 1:
                self._datagram()
        else:
            self._dg[self._filled] = byte
            self._filled += 1
            if self._filled >= self._dg[0]:
                self._datagram()

    def _datagram(self) -> None:
        """A whole datagram is in the buffer: check the CRC, then dispatch (facts §1.4 steps 5-8)."""
        self._state = "idle"
        dg = self._dg
        length = dg[0]
        if length == 0:
            # The real firmware indexes before its buffer here; we report a CRC failure.
            self.error("CRC failed")
            self.text("DBG: DG: ")
            self.pulse_led("red", 100)
            return
        crc_rx = dg[length - 1]
        dg[length - 1] = 0                       # the firmware zeroes the CRC slot
        crc_ok = w.crc8(dg[:length - 1]) == crc_rx
        dg[0] = length - 1                       # ... and keeps LEN-1 in byte 0
        if not crc_ok:
            self.error("CRC failed")
            self.text("DBG: DG: " + "".join(f"{b:02x} " for b in dg[:dg[0]]))
            self.pulse_led("red", 100)
            return
        frame = w.Frame(dg[1], dg[2], bytes(dg[3:length - 1]))
        self.last_datagram = frame
        driven = self.demands != (0, 0)
        if dispatch(self, frame, length):
            if driven and self.demands == (0, 0):
                self.stop_received, self.stop_received_sim = self._last_rx, self.world.time
            self.pulse_led("blue", 2)
            self.packets_in = (self.packets_in + 1) & 0xFFFF

    # ================================================================== 1 ms timer

    def tick(self, now: float) -> None:
        """One millisecond of the board's timer and main loop, at simulated time ``now`` (s)."""
        with self.lock:
            self._update_encoders()
            if self.daemon_alive_source is not None:
                self.daemon_alive = bool(self.daemon_alive_source())
            if self.shutdown_reason is not None:
                self._shutdown_loop(now)
                return
            self._ms += 1
            for led in self.leds:
                if led["count"] > 0:
                    led["count"] -= 1
                    if led["count"] == 0:
                        led["state"] = 0
            if self.pid_on and self._ms % CONTROL_PERIOD_MS == 0:
                self.right.control()                 # right first, as the firmware
                self.left.control()
                self._drive(self.left.command * 2, self.right.command * 2)
            elif not self.pid_on:
                self._open_loop()
            if self._ms % ADC_PERIOD_MS == 0:
                self.volts.sample(self.world.battery_voltage * 1000)
                self.amps.sample(self.world.battery_current * 1000)
            self._supervise(now)

    def _update_encoders(self) -> None:
        counts = self.world.counts()
        for motor, new, old in zip((self.left, self.right), counts, self._world_counts,
                                   strict=True):
            delta = new - old
            if delta == 0:
                continue
            self.pulse_led("green", 2)
            if motor.enc_mode == 1:
                motor.position = int16(motor.position + delta)
            elif motor.enc_mode == 0:
                # Single channel: direction guessed from the PI output's sign.
                sign = (motor.command > 0) - (motor.command < 0)
                motor.position = int16(motor.position + sign * abs(delta))
            # mode 2: accepted, but its code is compiled out: the count never changes
        self._world_counts = counts

    def _drive(self, left_register: int, right_register: int) -> None:
        """Signed PWM duty registers (0..255 with sign) -> world duty fractions."""
        self.world.set_duty(clamp(left_register, 255) / 255, clamp(right_register, 255) / 255)

    def _open_loop(self) -> None:
        """DIP SW4 off: duty = |demand| x 2 truncated to 8 bits, direction per `Defects`."""
        registers = []
        for motor in (self.left, self.right):
            duty = (abs(motor.demand) * 2) & 0xFF
            sign_of = motor.command if self.defects.open_loop_stale_direction else motor.demand
            registers.append(-duty if sign_of < 0 else duty)
        self._drive(*registers)

    def _supervise(self, now: float) -> None:
        """Battery supervision and the PB7 handshake, every main-loop pass (facts §3.7-3.8)."""
        if self.volts.smooth < LOW_MV:
            self.hat.inverted = True
        if self.volts.smooth < SHUTDOWN_MV:
            self._enter_shutdown(" LOW VOLTAGE SHUTDOWN ", now)
        elif self.daemon_alive:
            self._daemon_seen = True
        elif self._daemon_seen:
            self._enter_shutdown(" TURN RaspberryPI OFF SAFELY ", now)

    def _enter_shutdown(self, message: str, now: float) -> None:
        self.shutdown_reason = message
        self._next_shutdown_print = now + 2.0    # message on the OLED for 2 s first
        self.hat.screen = 10
        self._state = "idle"
        # Timers 0/1/2 stop: no control, no LED timing, no ADC. The frozen PWM pin's
        # level is undefined; the model turns the motors off.
        self.world.set_duty(0.0, 0.0)

    def _shutdown_loop(self, now: float) -> None:
        assert self._next_shutdown_print is not None
        if now + 1e-9 >= self._next_shutdown_print:
            self.text("Low battery shutdown")
            self.shutdown_request = not self.defects.pb5_not_output
            self._next_shutdown_print += 5.0

    # ================================================================== test handles

    def set_battery_voltage(self, volts: float) -> None:
        """Set the world's battery (open-circuit) voltage, V."""
        self.world.set_battery_voltage(volts)

    def stall(self, wheel: str, on: bool = True) -> None:
        """Block the "left" or "right" wheel in the world."""
        self.world.stall(wheel, on)

    def press(self, button: str) -> None:
        """Press and release HAT button "S1".."S4"."""
        self.hat.press(button)

    def hold(self, button: str, down: bool = True) -> None:
        self.hat.hold(button, down)

    def set_dip(self, value: int) -> None:
        self.hat.set_dip(value)

    @property
    def demands(self) -> tuple[int, int]:
        """Velocity demands (left, right), as MOTOR_GET_VEL reports them."""
        with self.lock:
            return self.left.demand, self.right.demand

    def led_lit(self, name: str) -> bool:
        """Whether LED ``name`` (see `LED_NAMES`) is physically lit; LED 4 mirrors PB7."""
        with self.lock:
            if name == "led4":
                return self.daemon_alive
            return self.leds[LED_NAMES.index(name)]["state"] != 0

    @property
    def led_states(self) -> dict[str, bool]:
        """Every LED's physical state."""
        return {name: self.led_lit(name) for name in LED_NAMES}

    # ================================================================== helpers

    def zero_encoders(self) -> None:
        """Both counts and previous samples := 0 (MULTI_CLEAR_DATA, HAT S3 on ENCODERS)."""
        for motor in (self.left, self.right):
            motor.position = motor.position_prev = 0

    def pulse_led(self, name: str, ms: int) -> None:
        led = self.leds[LED_NAMES.index(name)]
        led["count"] = ms
        led["state"] = 1

    def error(self, message: str, red_ms: int | None = None) -> None:
        """The firmware's errmessage(): ERR line, error screen, error count."""
        message = message[:79]
        self.errors = (self.errors + 1) & 0xFFFF
        self.hat.error_text = message
        self.hat.screen = 7
        self.text(f"ERR: {message}")
        if red_ms is not None:
            self.pulse_led("red", red_ms)

    def text(self, line: str) -> None:
        """Send one line of text (no prefix added)."""
        self.text_sent.append(line)
        self.transmit(line.encode("ascii", "replace") + b"\n")
