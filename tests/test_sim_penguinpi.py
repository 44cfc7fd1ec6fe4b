"""The PenguinPi firmware model, byte for byte against penguinpi-facts.md.

Most tests drive the model directly with exact simulated time (`SimClock.run`);
the last ones go through a real pseudo-terminal with pyserial, as hwbridge does.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import serial

from icefloe.config import Board, Geometry
from icefloe.sim.clock import SimClock
from icefloe.sim.penguinpi import PenguinPiSim
from icefloe.sim.penguinpi_firmware import Defects, PenguinPiFirmware
from icefloe.sim.pty_link import LineFaults
from icefloe.sim.world import World
from icefloe.wire import penguinpi as w

A, M, MU, L, ADC, H = w.Address, w.MotorOp, w.MultiOp, w.LedOp, w.AdcOp, w.HatOp


class Bench:
    """A firmware model on a bench: a world, a clock, and the bytes the board sent, parsed."""

    def __init__(self, defects: Defects | None = None, dip: int = 0b0001) -> None:
        self.world = World(Geometry(), seed=1)
        self.sent = bytearray()
        self.fw = PenguinPiFirmware(self.world, transmit=self.sent.extend, defects=defects,
                                    dip=dip)
        self.fw.start()
        self.clock = SimClock(self.world, [self.fw])
        self.parser = w.Parser()
        self.link_time = 0.0
        self.boot = self.events()

    def send(self, data: bytes) -> list[w.Event]:
        """Bytes from the host, back-to-back; returns what the board sent in answer."""
        self.link_time += 0.01
        self.fw.receive(data, self.link_time)
        return self.events()

    def request(self, address: int, opcode: int, payload: bytes = b"") -> list[w.Event]:
        return self.send(w.encode_frame(address, opcode, payload))

    def events(self) -> list[w.Event]:
        events = self.parser.feed(bytes(self.sent))
        self.sent.clear()
        return events

    def get(self, address: int, opcode: int) -> bytes:
        """A GET that must be answered with exactly one frame; returns its payload."""
        events = self.request(address, opcode)
        assert len(events) == 1 and isinstance(events[0], w.Frame), events
        assert (events[0].address, events[0].opcode) == (address, opcode)
        return events[0].payload


@pytest.fixture
def bench() -> Bench:
    b = Bench()
    assert b.boot == [w.TextLine("DBG: starting main loop")]
    return b


def texts(events: list[w.Event]) -> list[str]:
    return [e.text for e in events if isinstance(e, w.TextLine)]


# --------------------------------------------------------------------------- motors


def test_demand_50_gives_100_counts_per_200ms(bench: Bench) -> None:
    """facts §3.3: steady speed = 10 x demand counts/s, i.e. +100 counts per 0.2 s at demand 50."""
    assert bench.request(A.AD_MULTI, MU.MULTI_SET_VEL, w.pack_multi_set(50, 50)) == []
    bench.clock.run(2.0)                                   # settle
    before = w.unpack_multi_get(bench.get(A.AD_MULTI, MU.MULTI_GET_ENC))
    for _ in range(5):
        bench.clock.run(0.2)
        after = w.unpack_multi_get(bench.get(A.AD_MULTI, MU.MULTI_GET_ENC))
        assert after[0] - before[0] == pytest.approx(100, abs=3)
        assert after[1] - before[1] == pytest.approx(100, abs=3)
        before = after
    # The PI output sits where 10 counts/20 ms needs it: PWM = |cmd| x 2 / 255.
    assert bench.world.duty[0] == pytest.approx(bench.fw.left.command * 2 / 255)


def test_multi_set_is_right_then_left_and_get_is_left_then_right(bench: Bench) -> None:
    # Wire payload "14 EC": byte 0 = RIGHT +20, byte 1 = LEFT -20 (facts §1.3 vectors).
    bench.send(bytes.fromhex("11 06 13 82 14 EC E7"))
    assert (bench.fw.right.demand, bench.fw.left.demand) == (20, -20)
    assert w.unpack_int16(bench.get(A.AD_MOTOR_R, M.MOTOR_GET_VEL)) == 20
    assert w.unpack_int16(bench.get(A.AD_MOTOR_L, M.MOTOR_GET_VEL)) == -20
    bench.clock.run(1.0)
    left, right = w.unpack_multi_get(bench.get(A.AD_MULTI, MU.MULTI_GET_ENC))
    assert left < 0 < right
    assert left == w.unpack_int16(bench.get(A.AD_MOTOR_L, M.MOTOR_GET_ENC))
    assert right == w.unpack_int16(bench.get(A.AD_MOTOR_R, M.MOTOR_GET_ENC))



def test_a_stops_receipt_is_the_link_time_of_the_datagram_that_zeroed_both_demands(bench: Bench) -> None:
    """What a test times a stop to (tests/test_box.py): the arrival of the datagram that took the wheels
    from driven to both zero; a zero demand to standing wheels, or one wheel zeroed, is no stop."""
    assert bench.fw.stop_received == -1.0
    bench.request(A.AD_MULTI, MU.MULTI_SET_VEL, w.pack_multi_set(0, 0))  # standing: no stop
    assert bench.fw.stop_received == -1.0
    bench.request(A.AD_MULTI, MU.MULTI_SET_VEL, w.pack_multi_set(30, 30))
    bench.request(A.AD_MOTOR_L, M.MOTOR_SET_VEL, w.pack_int16(0))  # one wheel still driven
    assert bench.fw.stop_received == -1.0
    bench.request(A.AD_MULTI, MU.MULTI_SET_VEL_GET_ENC, w.pack_multi_set(0, 0))
    assert bench.fw.stop_received == bench.link_time
    received = bench.link_time
    bench.request(A.AD_MULTI, MU.MULTI_ALL_STOP)  # stopped already: the first receipt stays
    assert bench.fw.stop_received == received
    bench.request(A.AD_MULTI, MU.MULTI_SET_VEL, w.pack_multi_set(-20, 10))
    bench.request(A.AD_MULTI, MU.MULTI_ALL_STOP)
    assert bench.fw.stop_received == bench.link_time > received

def test_gains_defaults_and_set(bench: Bench) -> None:
    assert w.unpack_int16(bench.get(A.AD_MOTOR_L, M.MOTOR_GET_KVP)) == 0
    assert w.unpack_int16(bench.get(A.AD_MOTOR_L, M.MOTOR_GET_KVI)) == 1
    assert bench.get(A.AD_MOTOR_L, M.MOTOR_GET_ENC_MODE) == b"\x01"
    assert bench.get(A.AD_MOTOR_L, M.MOTOR_GET_CONTROL_MODE) == b"\x00"
    bench.request(A.AD_MOTOR_L, M.MOTOR_SET_KVP, w.pack_int16(3))
    assert w.unpack_int16(bench.get(A.AD_MOTOR_L, M.MOTOR_GET_KVP)) == 3
    assert w.unpack_int16(bench.get(A.AD_MOTOR_R, M.MOTOR_GET_KVP)) == 0


def test_encoder_wraps_int16_and_clear_data(bench: Bench) -> None:
    bench.fw.left.position = bench.fw.left.position_prev = 32700
    bench.fw.right.position = bench.fw.right.position_prev = -32700
    bench.request(A.AD_MULTI, MU.MULTI_SET_VEL, w.pack_multi_set(left=50, right=-50))
    bench.clock.run(1.5)
    left, right = w.unpack_multi_get(bench.get(A.AD_MULTI, MU.MULTI_GET_ENC))
    assert left < 0 < right                              # wrapped through +-32768
    # The controller's int16 differences are wrap-safe: it still measures ~10 counts/20 ms.
    assert bench.fw.left.measured == pytest.approx(10, abs=2)
    assert bench.fw.right.measured == pytest.approx(-10, abs=2)
    bench.request(A.AD_MULTI, MU.MULTI_CLEAR_DATA)
    assert w.unpack_multi_get(bench.get(A.AD_MULTI, MU.MULTI_GET_ENC)) == (0, 0)
    assert bench.fw.left.position_prev == 0 and bench.fw.demands == (0, 0)


@pytest.mark.parametrize("fixed", [False, True])
def test_enc_zero_velocity_spike(fixed: bool) -> None:
    bench = Bench(Defects.fixed() if fixed else None)
    bench.request(A.AD_MULTI, MU.MULTI_SET_VEL, w.pack_multi_set(50, 50))
    bench.clock.run(1.0)
    bench.request(A.AD_MOTOR_L, M.MOTOR_SET_ENC_ZERO)
    assert w.unpack_int16(bench.get(A.AD_MOTOR_L, M.MOTOR_GET_ENC)) == 0
    bench.clock.run(0.02)
    # Real firmware: previous sample kept, so the next "measured" speed is hugely negative.
    assert (bench.fw.left.measured < -100) is not fixed
    assert abs(bench.fw.right.measured - 10) <= 2


def test_encoder_mode_wants_four_bytes(bench: Bench) -> None:
    events = bench.request(A.AD_MOTOR_L, M.MOTOR_SET_ENC_MODE, b"\x00")
    assert texts(events) == ["ERR: bad datagram length (4) for MOTOR_SET_ENC_MODE"]
    assert bench.request(A.AD_MOTOR_L, M.MOTOR_SET_ENC_MODE, b"\x00\x00\x00\x00") == []
    assert bench.get(A.AD_MOTOR_L, M.MOTOR_GET_ENC_MODE) == b"\x00"
    events = bench.request(A.AD_MOTOR_L, M.MOTOR_SET_ENC_MODE, b"\x07\x00\x00\x00")
    assert texts(events) == ["ERR: bad encoder mode set 7"]
    fixed = Bench(Defects.fixed())
    assert fixed.request(A.AD_MOTOR_L, M.MOTOR_SET_ENC_MODE, b"\x02") == []
    assert fixed.get(A.AD_MOTOR_L, M.MOTOR_GET_ENC_MODE) == b"\x02"
    assert texts(fixed.request(A.AD_HAT, H.HAT_SET_SCREEN)) == [
        "ERR: bad datagram length (3) for HAT_SET_SCREEN"]


def test_encoder_modes_0_and_2(bench: Bench) -> None:
    four = b"\x00\x00\x00"
    bench.request(A.AD_MOTOR_L, M.MOTOR_SET_ENC_MODE, b"\x00" + four)   # single channel
    bench.request(A.AD_MOTOR_R, M.MOTOR_SET_ENC_MODE, b"\x02" + four)   # compiled out
    bench.request(A.AD_MULTI, MU.MULTI_SET_VEL, w.pack_multi_set(-40, 40))
    bench.clock.run(1.0)
    left, right = w.unpack_multi_get(bench.get(A.AD_MULTI, MU.MULTI_GET_ENC))
    assert left < -100                       # counted with the sign of the PI output
    assert right == 0                        # mode 2 never counts
    assert bench.world.counts()[1] > 100     # although the wheel turned


def test_current_adc_follows_the_motors(bench: Bench) -> None:
    idle = w.unpack_float(bench.get(A.AD_ADC_C, ADC.ADC_GET_SMOOTH))
    assert idle == pytest.approx(bench.world.battery_current * 1000, abs=4)   # mA
    bench.request(A.AD_MULTI, MU.MULTI_SET_VEL, w.pack_multi_set(80, 80))
    bench.fw.stall("left")
    bench.clock.run(1.0)
    loaded = w.unpack_float(bench.get(A.AD_ADC_C, ADC.ADC_GET_SMOOTH))
    assert loaded > idle + 100


def test_open_loop_mode_uses_stale_direction() -> None:
    bench = Bench(dip=0b0000)                # SW4 off, but PI control stays on until a HAT interrupt
    assert bench.fw.pid_on
    bench.request(A.AD_MULTI, MU.MULTI_SET_VEL, w.pack_multi_set(40, 40))
    bench.clock.run(1.0)
    bench.fw.hat.press("S4")                 # any HAT interrupt reads SW4 -> open loop
    assert not bench.fw.pid_on
    bench.request(A.AD_MULTI, MU.MULTI_SET_VEL, w.pack_multi_set(-40, -40))
    bench.clock.run(0.01)
    assert bench.world.duty == (80 / 255, 80 / 255)   # |demand| x 2, sign of the stale command
    fixed = Bench(Defects.fixed(), dip=0)
    fixed.fw.hat.press("S4")
    fixed.request(A.AD_MULTI, MU.MULTI_SET_VEL, w.pack_multi_set(-40, -40))
    fixed.clock.run(0.01)
    assert fixed.world.duty == (-80 / 255, -80 / 255)


# --------------------------------------------------------------------------- errors


GOOD = (A.AD_MOTOR_L, M.MOTOR_GET_ENC)


@pytest.mark.parametrize(("bad", "expected", "red_ms"), [
    (w.encode_frame(A.AD_MOTOR_L, M.MOTOR_GET_ENC, b"\x00"),
     ["ERR: bad datagram length (4) for MOTOR_GET_ENC"], 0),
    (bytes.fromhex("11 06 12 01 00 32 85"), ["ERR: CRC failed", "DBG: DG: 05 12 01 00 32 "], 100),
    (w.encode_frame(0x20, 0x80), ["ERR: Datagram: unknown address 32"], 100),
    (w.encode_frame(A.AD_MOTOR_L, 0x99), ["ERR: bad motor opcode 153"], 0),
    (w.encode_frame(A.AD_MULTI, 0x07), ["ERR: bad Multi opcode 7"], 0),
    (w.encode_frame(A.AD_LED_2, 0x82), ["ERR: bad LED opcode 130"], 0),
    (w.encode_frame(A.AD_ADC_V, 0x85), ["ERR: bad ADC opcode 133"], 0),
    (w.encode_frame(A.AD_HAT, 0x15), ["ERR: bad HAT opcode 21", "ERR: Datagram: unknown address 96"],
     100),
    (w.encode_frame(A.AD_HAT, H.HAT_SET_SCREEN), ["ERR: bad datagram length (3) for HAT_SET_IP_ETH"],
     0),
])
def test_bad_datagram_gives_err_text_no_reply_and_next_is_answered(
        bench: Bench, bad: bytes, expected: list[str], red_ms: int) -> None:
    errors = bench.fw.errors
    events = bench.send(bad)
    assert events == [w.TextLine(t) for t in expected]         # text only: no reply frame
    assert bench.fw.errors == errors + sum(t.startswith("ERR") for t in expected)
    assert bench.fw.hat.screen == 7                            # any error shows the ERROR screen
    assert bench.fw.leds[0] == {"state": int(red_ms > 0), "count": red_ms}
    assert bench.fw.packets_in == 0
    assert len(bench.get(*GOOD)) == 2                          # the next good request is answered
    assert bench.fw.packets_in == 1


def test_datagram_too_long_then_rest_is_user_text(bench: Bench) -> None:
    events = bench.send(b"\x11\x0cAB")
    assert texts(events) == ["ERR: Datagram too long 12"]
    assert bench.fw.hat.user_lines[3] == "AB"
    assert bench.fw.leds[0] == {"state": 1, "count": 250}


def test_serial_timeout_between_bytes(bench: Bench) -> None:
    frame = w.encode_frame(*GOOD)
    bench.fw.receive(frame[:3], 1.0)
    bench.fw.receive(frame[3:], 1.0 + 150e-6)           # within 200 µs: still one datagram
    assert [type(e) for e in bench.events()] == [w.Frame]
    bench.fw.receive(frame[:3], 2.0)
    bench.fw.poll(2.0 + 100e-6)
    assert bench.events() == []
    bench.fw.poll(2.0 + 300e-6)
    assert texts(bench.events()) == ["ERR: Serial timeout"]
    bench.fw.receive(frame[3:], 2.001)                   # late bytes become user text
    assert bench.events() == []
    assert bench.fw.hat.user_lines[3] == "\x82\x01"


def test_uart_error_inside_frame_becomes_zero_byte(bench: Bench) -> None:
    frame = w.encode_frame(A.AD_MOTOR_L, M.MOTOR_SET_VEL, w.pack_int16(300))
    bench.fw.receive(frame[:4], 1.0)
    bench.fw.receive_error(1.0, "Bad UART frame")
    bench.fw.receive(frame[5:], 1.0)
    assert texts(bench.events()) == ["ERR: Bad UART frame", "ERR: CRC failed",
                                     "DBG: DG: 05 12 01 00 2c "]


def test_statistics_and_last_datagram(bench: Bench) -> None:
    bench.request(A.AD_LED_2, L.LED_SET_STATE, b"\x01")
    bench.get(A.AD_LED_2, L.LED_GET_STATE)
    bench.send(bytes.fromhex("11 04 12 82 00"))
    assert (bench.fw.packets_in, bench.fw.packets_out, bench.fw.errors) == (2, 1, 1)
    assert bench.fw.last_datagram == w.Frame(A.AD_LED_2, L.LED_GET_STATE)


# --------------------------------------------------------------------------- user text


def test_user_text_buffer_rules(bench: Bench) -> None:
    hat = bench.fw.hat
    assert bench.send(b"hello\x00") == []
    assert hat.user_lines == ["USER TEXT", "", "", "hello"]
    bench.send(b"\nworld")
    assert hat.user_lines == ["", "", "hello", "world"]
    bench.send(b"x" * 16)                               # 21st char scrolls
    assert hat.user_lines[2:] == ["worldxxxxxxxxxxxxxxx", "x"]
    bench.send(b"\n\f")
    assert hat.user_lines == ["USER TEXT", "", "", ""]
    bench.send(b"a")                                    # \f kept the scroll flag (sic)
    assert hat.user_lines == ["", "", "", "a"]


# --------------------------------------------------------------------------- LEDs, ADC


def test_led_count_and_pulses(bench: Bench) -> None:
    bench.request(A.AD_LED_R, L.LED_SET_COUNT, b"\xc8")    # 200 ms
    assert bench.get(A.AD_LED_R, L.LED_GET_STATE) == b"\x01"
    bench.clock.run(0.199)
    assert bench.fw.leds[0]["state"] == 1
    bench.clock.run(0.001)
    assert bench.get(A.AD_LED_R, L.LED_GET_STATE) == b"\x00"
    assert bench.fw.leds[2]["state"] == 1                  # blue: last datagram dispatched
    bench.clock.run(0.002)
    assert bench.fw.leds[2]["state"] == 0
    bench.request(A.AD_LED_3, L.LED_SET_COUNT, b"\x00")    # count 0: on indefinitely
    bench.clock.run(0.5)
    assert bench.get(A.AD_LED_3, L.LED_GET_STATE) == b"\x01"


def test_adc_defaults_and_smoothing(bench: Bench) -> None:
    assert bench.get(A.AD_ADC_V, ADC.ADC_GET_SCALE) == bytes.fromhex("41 80 25 E2")
    assert bench.get(A.AD_ADC_C, ADC.ADC_GET_SCALE) == bytes.fromhex("40 4E 40 00")
    assert bench.get(A.AD_ADC_V, ADC.ADC_GET_POLE) == bytes.fromhex("3F 73 33 33")
    volts = bench.world.battery_voltage
    smooth = w.unpack_float(bench.get(A.AD_ADC_V, ADC.ADC_GET_SMOOTH))
    # Firmware scale 16.018 mV/count vs hardware 16.11: reads ~0.6 % low, as the real board.
    assert smooth == pytest.approx(volts * 1000 * 16.018497 / 16.11328, abs=16)
    assert len(bench.get(A.AD_ADC_V, ADC.ADC_GET_VALUE)) == 2      # sic: a float's low bytes
    bench.request(A.AD_ADC_V, ADC.ADC_SET_POLE, w.pack_float(0.0))  # no filtering
    bench.world.set_battery_voltage(7.5)
    bench.clock.run(0.05)
    smooth = w.unpack_float(bench.get(A.AD_ADC_V, ADC.ADC_GET_SMOOTH))
    assert smooth == pytest.approx(bench.world.battery_voltage * 1000 * 0.99412, abs=16)
    fixed = Bench(Defects.fixed())
    assert len(fixed.get(A.AD_ADC_V, ADC.ADC_GET_VALUE)) == 4


# --------------------------------------------------------------------------- HAT


def test_dip_boot_quirk_and_buttons(bench: Bench) -> None:
    assert bench.get(A.AD_HAT, H.HAT_GET_DIP) == b"\x10"       # SW4 on, x16 at boot
    bench.fw.hat.press("S4")
    bench.fw.hat.press("S4")
    assert bench.get(A.AD_HAT, H.HAT_GET_DIP) == b"\x01"
    assert bench.get(A.AD_HAT, H.HAT_GET_BUTTON) == b"\x02"
    assert bench.get(A.AD_HAT, H.HAT_GET_BUTTON) == b"\x00"    # read resets
    assert Bench(Defects.fixed()).get(A.AD_HAT, H.HAT_GET_DIP) == b"\x01"


def test_buttons_screens_stop_and_beacon(bench: Bench) -> None:
    hat = bench.fw.hat
    for expected in (1, 2, 3):
        hat.press("S1")
        assert hat.screen == expected
    assert hat.screen_name == "ENCODERS"
    bench.request(A.AD_HAT, H.HAT_SET_SCREEN, b"\x08")
    hat.press("S1")
    assert hat.screen == 0                                    # wraps at 9
    bench.request(A.AD_MULTI, MU.MULTI_SET_VEL, w.pack_multi_set(30, 30))
    hat.press("S2")
    assert (bench.fw.left.demand, bench.fw.right.demand) == (0, 0)
    bench.request(A.AD_HAT, H.HAT_SET_SCREEN, b"\x04")        # PID screen: S3 = test
    hat.press("S3")
    assert (bench.fw.right.demand, bench.fw.left.demand) == (30, -30)
    bench.request(A.AD_HAT, H.HAT_SET_LEDARRAY, w.pack_uint16(0x1234))
    assert hat.ledarray_out == 0x1234
    hat.set_dip(0b0011)                                       # SW3 beacon on
    assert hat.ledarray_out == 0x9008
    assert w.unpack_uint16(bench.get(A.AD_HAT, H.HAT_GET_LEDARRAY)) == 0x1234


def test_ip_and_mac(bench: Bench) -> None:
    bench.send(bytes.fromhex("11 08 60 11 C0 A8 01 0A 49"))
    bench.send(bytes.fromhex("11 0A 60 14 B8 27 EB 01 02 03 88"))
    assert bench.fw.hat.ip_wlan == (192, 168, 1, 10)
    assert bench.fw.hat.mac_wlan == (0xB8, 0x27, 0xEB, 1, 2, 3)


# --------------------------------------------------------------------------- battery, shutdown


@pytest.mark.parametrize("fixed", [False, True])
def test_low_battery_inverts_then_shuts_down_for_good(fixed: bool) -> None:
    bench = Bench(Defects.fixed() if fixed else None)
    bench.world.set_battery_voltage(6.95)
    bench.clock.run(0.5)
    assert bench.fw.hat.inverted and bench.fw.shutdown_reason is None
    bench.world.set_battery_voltage(6.4)
    while bench.fw.shutdown_reason is None and bench.clock.now < 2.0:
        bench.clock.step()                                    # until the filtered value drops
    assert bench.fw.shutdown_reason == " LOW VOLTAGE SHUTDOWN "
    assert bench.world.duty == (0.0, 0.0)
    assert bench.request(*GOOD) == []                         # no datagrams processed any more
    bench.clock.run(1.998)
    assert texts(bench.events()) == []
    bench.clock.run(0.002)                                    # 2 s after entering
    assert texts(bench.events()) == ["Low battery shutdown"]
    bench.clock.run(4.998)
    assert texts(bench.events()) == []
    bench.clock.run(0.002)
    assert texts(bench.events()) == ["Low battery shutdown"]
    assert bench.fw.shutdown_request is fixed                 # PB5 never driven on the real board
    bench.world.set_battery_voltage(8.2)
    bench.clock.run(1.0)
    assert bench.fw.shutdown_reason is not None              # only a reset recovers


def test_daemon_handshake_shutdown(bench: Bench) -> None:
    bench.clock.run(0.1)
    assert bench.fw.shutdown_reason is None                   # PB7 low, never seen high
    bench.fw.daemon_alive = True
    bench.clock.run(0.1)
    assert bench.fw.led_lit("led4")                           # LED 4 mirrors PB7
    bench.fw.daemon_alive = False
    bench.clock.run(0.001)
    assert bench.fw.shutdown_reason == " TURN RaspberryPI OFF SAFELY "


def test_line_faults_are_seeded_and_exact() -> None:
    faults = LineFaults(seed=3)
    faults.drop(2, after=1)
    assert faults.apply(b"abcde", "rx") == b"ade"
    assert faults.apply(b"xyz", "tx") == b"xyz"          # the other direction is clean
    faults.noise(1.0, "tx")
    noisy = faults.apply(bytes(100), "tx")
    assert all(bin(b).count("1") == 1 for b in noisy)    # exactly one bit flipped per byte
    again = LineFaults(seed=3)
    again.drop(2, after=1)
    again.apply(b"abcde", "rx")
    again.noise(1.0, "tx")
    assert again.apply(bytes(100), "tx") == noisy
    with pytest.raises(ValueError, match="direction"):
        faults.drop(1, "up")
    with pytest.raises(ValueError, match="probability"):
        faults.noise(2.0)


# --------------------------------------------------------------------------- over a real serial port


@pytest.fixture
def live(tmp_path: Path):
    """A PenguinPiSim behind a pty, its world stepped in real time by a clock thread."""
    world = World(Geometry(), seed=1)
    board = Board(serial_port=str(tmp_path / "dev" / "ttyPPI"))
    sim = PenguinPiSim(world, board)
    # The port first: pyserial flushes the input when it opens it, so a board that had already
    # said its first line (the clock's first step) would have it thrown away.
    port = serial.Serial(board.serial_port, 115200, timeout=0.5, exclusive=True)
    clock = SimClock(world, [sim]).start()
    yield sim, port
    port.close()
    clock.stop()
    sim.close()
    assert not Path(board.serial_port).exists()


def transact(port: serial.Serial, parser: w.Parser, request: bytes,
             want: int = 1, timeout: float = 10.0) -> list[w.Event]:
    """Write one request; collect events until ``want`` have arrived or ``timeout`` passes (a
    condition, not a pause: generous, for a machine whose cores are busy with other work)."""
    port.write(request)
    events: list[w.Event] = []
    deadline = time.monotonic() + timeout
    while len(events) < want and time.monotonic() < deadline:
        events += parser.feed(port.read(max(1, port.in_waiting)))
    return events


def test_over_pyserial(live) -> None:
    sim, port = live
    parser = w.Parser()
    assert transact(port, parser, b"") == [w.TextLine("DBG: starting main loop")]
    with pytest.raises(serial.SerialException):               # exclusive, like /dev/serial0
        serial.Serial(str(sim.link.path), 115200, exclusive=True)
    reply = transact(port, parser, w.encode_frame(A.AD_MULTI, MU.MULTI_SET_VEL_GET_ENC,
                                                  w.pack_multi_set(50, 50)))
    assert isinstance(reply[0], w.Frame) and reply[0].opcode == MU.MULTI_SET_VEL_GET_ENC
    time.sleep(0.5)
    reply = transact(port, parser, w.encode_frame(A.AD_MULTI, MU.MULTI_GET_ENC))
    left, right = w.unpack_multi_get(reply[0].payload)
    assert left > 50 and right > 50
    # A corrupted request: ERR + DBG lines, no reply; the next request is answered.
    assert texts(transact(port, parser, bytes.fromhex("11 04 12 82 00"), want=2)) == [
        "ERR: CRC failed", "DBG: DG: 03 12 82 "]
    # Two bytes lost on the line: the board times out, the host still gets the next reply.
    sim.model.line.drop(2, after=3)
    events = transact(port, parser, w.encode_frame(*GOOD), want=1)
    assert texts(events) == ["ERR: Serial timeout"]
    reply = transact(port, parser, w.encode_frame(*GOOD))
    assert isinstance(reply[-1], w.Frame) and reply[-1].address == A.AD_MOTOR_L
    transact(port, parser, w.encode_frame(A.AD_MULTI, MU.MULTI_ALL_STOP), want=0, timeout=0)


def test_replies_are_paced_at_the_baud_rate(live) -> None:
    _, port = live
    parser = w.Parser()
    transact(port, parser, b"")
    byte_time = 10 / 115200
    # One round trip: a 5-byte request in, a 7-byte reply out.
    start = time.monotonic()
    assert len(transact(port, parser, w.encode_frame(*GOOD))) == 1
    assert time.monotonic() - start >= 12 * byte_time
    # 20 requests in one write: 20 replies x 9 bytes can leave no faster than the line allows.
    start = time.monotonic()
    events = transact(port, parser, w.encode_frame(A.AD_MULTI, MU.MULTI_GET_ENC) * 20, want=20)
    assert len(events) == 20
    assert time.monotonic() - start >= 20 * 9 * byte_time


def test_noisy_replies_are_survived_over_pyserial(live) -> None:
    sim, port = live
    parser = w.Parser()
    transact(port, parser, b"")
    sim.model.line.noise(0.05, "tx")
    for _ in range(40):
        transact(port, parser, w.encode_frame(A.AD_MULTI, MU.MULTI_GET_ENC), timeout=0.05)
    sim.model.line.noise(0.0, "tx")
    assert sim.model.line.corrupted["tx"] > 0
    assert parser.crc_errors + parser.length_errors + parser.garbage > 0
    # Clean again: the very next request is answered and decoded.
    time.sleep(0.05)
    port.reset_input_buffer()
    parser.reset()
    reply = transact(port, parser, w.encode_frame(*GOOD))
    assert isinstance(reply[-1], w.Frame) and reply[-1].opcode == M.MOTOR_GET_ENC
