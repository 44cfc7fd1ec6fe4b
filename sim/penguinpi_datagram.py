"""Datagram dispatch of the PenguinPi firmware model: one handler per device (facts §2).

Each handler checks the opcode and the exact payload length as the firmware
does, runs the command and returns the reply payload for GET opcodes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from icefloe.wire import penguinpi as w

from .penguinpi_parts import Adc, Motor, int16

if TYPE_CHECKING:
    from .penguinpi_firmware import PenguinPiFirmware

LED_ADDRESSES = {w.Address.AD_LED_R + i: i for i in range(6)}
"""LED address -> index in the firmware's LED table (red, green, blue, 2, 3, 4)."""


def dispatch(fw: PenguinPiFirmware, frame: w.Frame, length: int) -> bool:
    """Run one datagram (``length`` = its LEN byte); False if it was rejected (error reported)."""
    address = frame.address
    run: Callable[[int, bytes], bytes | None]
    if address in (w.Address.AD_MOTOR_R, w.Address.AD_MOTOR_L):
        motor = fw.right if address == w.Address.AD_MOTOR_R else fw.left
        run = lambda op, payload: _motor(fw, motor, op, payload)  # noqa: E731
        return _handle(fw, frame, length, w.MOTOR_OPS, "motor", run)
    if address == w.Address.AD_MULTI:
        return _handle(fw, frame, length, w.MULTI_OPS, "Multi", lambda op, p: _multi(fw, op, p))
    if address in LED_ADDRESSES:
        led = fw.leds[LED_ADDRESSES[address]]
        return _handle(fw, frame, length, w.LED_OPS, "LED", lambda op, p: _led(led, op, p))
    if address in (w.Address.AD_ADC_V, w.Address.AD_ADC_C):
        adc = fw.volts if address == w.Address.AD_ADC_V else fw.amps
        return _handle(fw, frame, length, w.ADC_OPS, "ADC", lambda op, p: _adc(fw, adc, op, p))
    # Anything else is offered to the HAT, which accepts only 0x60 (facts §2.6); a bad
    # HAT opcode makes it decline too, hence two errors.
    if address == w.Address.AD_HAT:
        if frame.opcode in w.HAT_OPS:
            return _handle(fw, frame, length, w.HAT_OPS, "HAT", fw.hat.datagram)
        fw.error(f"bad HAT opcode {frame.opcode}")
    fw.error(f"Datagram: unknown address {address}")
    fw.pulse_led("red", 100)
    return False


def _handle(fw: PenguinPiFirmware, frame: w.Frame, length: int, table: dict[int, w.OpSpec],
            dev: str, run: Callable[[int, bytes], bytes | None]) -> bool:
    """Check opcode and exact payload length, run the handler, send its reply if any."""
    spec = table.get(frame.opcode)
    if spec is None:
        fw.error(f"bad {dev} opcode {frame.opcode}")
        return False
    want, name = _expected(fw, spec)
    if length - 1 != want + 3:
        fw.error(f"bad datagram length ({length - 1}) for {name}")
        return False
    reply = run(frame.opcode, frame.payload)
    if reply is not None:
        fw.transmit(w.encode_frame(frame.address, frame.opcode, reply))
        fw.packets_out = (fw.packets_out + 1) & 0xFFFF
    return True


def _expected(fw: PenguinPiFirmware, spec: w.OpSpec) -> tuple[int, str]:
    """Payload length the firmware checks, and the name its length error prints."""
    d = fw.defects
    mode_op = spec.name in ("MOTOR_SET_ENC_MODE", "MOTOR_SET_CONTROL_MODE")
    if mode_op and not d.mode_ops_want_4_bytes:
        return 1, spec.name
    if spec.name == "HAT_SET_SCREEN" and d.screen_error_names_ip_eth:
        return spec.request_len, "HAT_SET_IP_ETH"
    return spec.request_len, spec.name


def _motor(fw: PenguinPiFirmware, motor: Motor, op: int, payload: bytes) -> bytes | None:
    M = w.MotorOp
    if op == M.MOTOR_SET_VEL:
        motor.demand = w.unpack_int16(payload)
    elif op == M.MOTOR_SET_KVP:
        motor.kvp = w.unpack_int16(payload)
    elif op == M.MOTOR_SET_KVI:
        motor.kvi = w.unpack_int16(payload)
    elif op == M.MOTOR_SET_ENC_ZERO:
        motor.position = 0
        if not fw.defects.enc_zero_keeps_prev:
            motor.position_prev = 0
    elif op == M.MOTOR_SET_ENC_MODE:
        if payload[0] in (0, 1, 2):
            motor.enc_mode = payload[0]
        else:
            fw.error(f"bad encoder mode set {payload[0]}")
    elif op == M.MOTOR_SET_CONTROL_MODE:
        motor.control_mode = payload[0]   # stored, used nowhere (as the firmware)
    elif op == M.MOTOR_GET_ENC_MODE:
        return bytes((motor.enc_mode & 0xFF,))
    elif op == M.MOTOR_GET_CONTROL_MODE:
        return bytes((motor.control_mode & 0xFF,))
    else:
        value = {M.MOTOR_GET_VEL: motor.demand, M.MOTOR_GET_ENC: motor.position,
                 M.MOTOR_GET_KVP: motor.kvp, M.MOTOR_GET_KVI: motor.kvi}[M(op)]
        return w.pack_int16(int16(value))
    return None


def _multi(fw: PenguinPiFirmware, op: int, payload: bytes) -> bytes | None:
    M = w.MultiOp
    if op in (M.MULTI_SET_VEL, M.MULTI_SET_VEL_GET_ENC):
        fw.left.demand, fw.right.demand = w.unpack_multi_set(payload)
    elif op in (M.MULTI_ALL_STOP, M.MULTI_CLEAR_DATA):
        fw.left.demand = fw.right.demand = 0
        if op == M.MULTI_CLEAR_DATA:
            fw.zero_encoders()
    if op in (M.MULTI_GET_ENC, M.MULTI_SET_VEL_GET_ENC):
        return w.pack_multi_get(fw.left.position, fw.right.position)
    return None


def _led(led: dict[str, int], op: int, payload: bytes) -> bytes | None:
    if op == w.LedOp.LED_SET_STATE:
        led["state"] = payload[0]
    elif op == w.LedOp.LED_SET_COUNT:
        led["count"] = payload[0]
        led["state"] = 1
    else:
        return bytes((led["state"],))
    return None


def _adc(fw: PenguinPiFirmware, adc: Adc, op: int, payload: bytes) -> bytes | None:
    A = w.AdcOp
    if op == A.ADC_SET_SCALE:
        adc.scale = w.unpack_float(payload)
    elif op == A.ADC_SET_POLE:
        adc.pole = w.unpack_float(payload)
    elif op == A.ADC_GET_SCALE:
        return w.pack_float(adc.scale)
    elif op == A.ADC_GET_POLE:
        return w.pack_float(adc.pole)
    elif op == A.ADC_GET_SMOOTH:
        return w.pack_float(adc.smooth)
    elif op == A.ADC_GET_VALUE:
        bits = w.pack_float(adc.value)
        # The C code reads a 16-bit int where a float was passed: its low 16 bits go out.
        return bits[2:] if fw.defects.adc_value_float_bits else bits
    return None
