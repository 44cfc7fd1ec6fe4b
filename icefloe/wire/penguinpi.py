"""The PenguinPi serial wire protocol, shared by the host (hwbridge) and the board model (sim).

A frame on the wire (both directions, 115200 baud 8N1, facts §1.2)::

    START=0x11  LEN  ADDRESS  OPCODE  PAYLOAD[0..6]  CRC

``LEN`` counts the bytes from LEN through CRC (4 + payload length); the CRC-8
covers LEN, ADDRESS, OPCODE and PAYLOAD. Opcodes with bit 7 set are GETs and the
board answers them with a frame of the same address and opcode; SETs are never
acknowledged. Multi-byte values are big-endian. Between frames the board sends
plain text lines (``ERR: ...``, ``DBG: ...``), which `Parser` hands back as
`TextLine` events.

Names follow the firmware's ``datagram.h`` so a student can grep for them.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

START = 0x11
"""First byte of every frame (ASCII DC1); not counted in LEN, not covered by the CRC."""
MIN_LEN = 4
"""LEN of a frame without payload: LEN, ADDRESS, OPCODE, CRC."""
MAX_LEN = 10
"""Largest LEN the firmware accepts (6 payload bytes, HAT_SET_MAC_WLAN)."""
MAX_PAYLOAD = MAX_LEN - MIN_LEN
GET_BIT = 0x80
"""Opcode bit 7: the sender expects a reply."""
CRC_POLY = 0x97
"""The firmware's shift-right constant (= normal polynomial 0xE9, reflected)."""


class Address(IntEnum):
    """Device addresses (facts §2.1). Only some are handled by the firmware."""

    AD_MOTORS = 0x10
    AD_MOTOR_R = 0x11
    AD_MOTOR_L = 0x12
    AD_MULTI = 0x13
    AD_SERVOS = 0x20
    AD_SERVO_A = 0x21
    AD_SERVO_B = 0x22
    AD_LEDS = 0x30
    AD_LED_R = 0x31
    AD_LED_G = 0x32
    AD_LED_B = 0x33
    AD_LED_2 = 0x34
    AD_LED_3 = 0x35
    AD_LED_4 = 0x36
    AD_ADCS = 0x40
    AD_ADC_V = 0x41
    AD_ADC_C = 0x42
    AD_HAT = 0x60


class MotorOp(IntEnum):
    """Opcodes for AD_MOTOR_R / AD_MOTOR_L (facts §2.2)."""

    MOTOR_SET_VEL = 0x01
    MOTOR_SET_KVP = 0x02
    MOTOR_SET_KVI = 0x03
    MOTOR_SET_ENC_ZERO = 0x04
    MOTOR_SET_ENC_MODE = 0x05
    MOTOR_SET_CONTROL_MODE = 0x06
    MOTOR_GET_VEL = 0x81
    MOTOR_GET_ENC = 0x82
    MOTOR_GET_KVP = 0x83
    MOTOR_GET_KVI = 0x84
    MOTOR_GET_ENC_MODE = 0x85
    MOTOR_GET_CONTROL_MODE = 0x86


class MultiOp(IntEnum):
    """Opcodes for AD_MULTI (facts §2.3).

    SET payloads are RIGHT then LEFT; GET replies are LEFT then RIGHT.
    """

    MULTI_SET_VEL = 0x01
    MULTI_ALL_STOP = 0x02
    MULTI_CLEAR_DATA = 0x03
    MULTI_GET_ENC = 0x81
    MULTI_SET_VEL_GET_ENC = 0x82


class LedOp(IntEnum):
    """Opcodes for AD_LED_R ... AD_LED_4 (facts §2.4)."""

    LED_SET_STATE = 0x01
    LED_SET_COUNT = 0x02
    LED_GET_STATE = 0x81


class AdcOp(IntEnum):
    """Opcodes for AD_ADC_V / AD_ADC_C (facts §2.5)."""

    ADC_SET_SCALE = 0x01
    ADC_SET_POLE = 0x02
    ADC_GET_SCALE = 0x81
    ADC_GET_POLE = 0x82
    ADC_GET_VALUE = 0x83
    ADC_GET_SMOOTH = 0x84


class HatOp(IntEnum):
    """Opcodes for AD_HAT (facts §2.6)."""

    HAT_SET_IP_ETH = 0x10
    HAT_SET_IP_WLAN = 0x11
    HAT_SET_SCREEN = 0x12
    HAT_SET_LEDARRAY = 0x13
    HAT_SET_MAC_WLAN = 0x14
    HAT_GET_DIP = 0xA0
    HAT_GET_BUTTON = 0xA1
    HAT_GET_LEDARRAY = 0xA2


class ServoOp(IntEnum):
    """Servo opcodes: defined in ``datagram.h`` but NOT implemented by the firmware (facts §2.7)."""

    SERVO_SET_POSITION = 0x01
    SERVO_SET_STATE = 0x02
    SERVO_SET_MIN_RANGE = 0x03
    SERVO_SET_MAX_RANGE = 0x04
    SERVO_SET_MIN_PWM = 0x05
    SERVO_SET_MAX_PWM = 0x06
    SERVO_GET_POSITION = 0x80
    SERVO_GET_STATE = 0x81
    SERVO_GET_MIN_RANGE = 0x82
    SERVO_GET_MAX_RANGE = 0x83
    SERVO_GET_MIN_PWM = 0x84
    SERVO_GET_MAX_PWM = 0x85


@dataclass(frozen=True, slots=True)
class OpSpec:
    """What the firmware expects of one opcode: exact request payload size and reply type."""

    name: str
    request_len: int
    """Payload bytes the firmware requires (it checks LEN == request_len + 4 exactly)."""
    reply: str | None
    """Reply type (facts §1.5): 'c' 1 byte, 'i' 2, 'h' 2x2, 'f' float; None = no reply."""


def _spec(op: IntEnum, request_len: int, reply: str | None = None) -> tuple[int, OpSpec]:
    return int(op), OpSpec(op.name, request_len, reply)


MOTOR_OPS: dict[int, OpSpec] = dict([
    _spec(MotorOp.MOTOR_SET_VEL, 2),
    _spec(MotorOp.MOTOR_SET_KVP, 2),
    _spec(MotorOp.MOTOR_SET_KVI, 2),
    _spec(MotorOp.MOTOR_SET_ENC_ZERO, 0),
    _spec(MotorOp.MOTOR_SET_ENC_MODE, 4),       # sic: 4 bytes, only byte 0 used (facts §8.8)
    _spec(MotorOp.MOTOR_SET_CONTROL_MODE, 4),   # sic, as above
    _spec(MotorOp.MOTOR_GET_VEL, 0, "i"),
    _spec(MotorOp.MOTOR_GET_ENC, 0, "i"),
    _spec(MotorOp.MOTOR_GET_KVP, 0, "i"),
    _spec(MotorOp.MOTOR_GET_KVI, 0, "i"),
    _spec(MotorOp.MOTOR_GET_ENC_MODE, 0, "c"),
    _spec(MotorOp.MOTOR_GET_CONTROL_MODE, 0, "c"),
])
MULTI_OPS: dict[int, OpSpec] = dict([
    _spec(MultiOp.MULTI_SET_VEL, 2),
    _spec(MultiOp.MULTI_ALL_STOP, 0),
    _spec(MultiOp.MULTI_CLEAR_DATA, 0),
    _spec(MultiOp.MULTI_GET_ENC, 0, "h"),
    _spec(MultiOp.MULTI_SET_VEL_GET_ENC, 2, "h"),
])
LED_OPS: dict[int, OpSpec] = dict([
    _spec(LedOp.LED_SET_STATE, 1),
    _spec(LedOp.LED_SET_COUNT, 1),
    _spec(LedOp.LED_GET_STATE, 0, "c"),
])
ADC_OPS: dict[int, OpSpec] = dict([
    _spec(AdcOp.ADC_SET_SCALE, 4),
    _spec(AdcOp.ADC_SET_POLE, 4),
    _spec(AdcOp.ADC_GET_SCALE, 0, "f"),
    _spec(AdcOp.ADC_GET_POLE, 0, "f"),
    _spec(AdcOp.ADC_GET_VALUE, 0, "i"),         # 2 bytes of a float's bit pattern (facts §8.9)
    _spec(AdcOp.ADC_GET_SMOOTH, 0, "f"),
])
HAT_OPS: dict[int, OpSpec] = dict([
    _spec(HatOp.HAT_SET_IP_ETH, 4),
    _spec(HatOp.HAT_SET_IP_WLAN, 4),
    _spec(HatOp.HAT_SET_SCREEN, 1),
    _spec(HatOp.HAT_SET_LEDARRAY, 2),
    _spec(HatOp.HAT_SET_MAC_WLAN, 6),
    _spec(HatOp.HAT_GET_DIP, 0, "c"),
    _spec(HatOp.HAT_GET_BUTTON, 0, "c"),
    _spec(HatOp.HAT_GET_LEDARRAY, 0, "i"),
])

REPLY_LEN = {"c": 1, "i": 2, "h": 4, "f": 4}
"""Payload bytes of each reply type."""


# --------------------------------------------------------------------------- CRC-8


def _crc_table() -> bytes:
    """CRC of every single byte value, computed with the firmware's bitwise loop (facts §1.3)."""
    table = bytearray(256)
    for value in range(256):
        crc = value
        for _ in range(8):
            crc = (crc >> 1) ^ CRC_POLY if crc & 1 else crc >> 1
        table[value] = crc
    return bytes(table)


_CRC_TABLE = _crc_table()


def crc8(data: bytes | bytearray | memoryview) -> int:
    """The PenguinPi CRC-8: init 0, XOR each byte in, 8 reflected shifts with 0x97, no final XOR.

    A table lookup per byte gives the same result as the firmware's 8-step loop.
    """
    crc = 0
    for byte in data:
        crc = _CRC_TABLE[crc ^ byte]
    return crc


# --------------------------------------------------------------------------- frames


def encode_frame(address: int, opcode: int, payload: bytes = b"") -> bytes:
    """One complete frame: START, LEN, ADDRESS, OPCODE, PAYLOAD, CRC.

    Raises ValueError naming the bad argument (address/opcode outside 0..255,
    payload longer than 6 bytes).
    """
    if not 0 <= address <= 0xFF:
        raise ValueError(f"address must be 0..255, got {address}")
    if not 0 <= opcode <= 0xFF:
        raise ValueError(f"opcode must be 0..255, got {opcode}")
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload must be at most {MAX_PAYLOAD} bytes, got {len(payload)}")
    body = bytes((MIN_LEN + len(payload), address, opcode)) + bytes(payload)
    return bytes((START,)) + body + bytes((crc8(body),))


@dataclass(frozen=True, slots=True)
class Frame:
    """A frame with a good CRC."""

    address: int
    opcode: int
    payload: bytes = b""

    @property
    def is_get(self) -> bool:
        """True if the opcode asks for a reply (bit 7)."""
        return bool(self.opcode & GET_BIT)


@dataclass(frozen=True, slots=True)
class TextLine:
    """A line of text between frames, without its newline (e.g. ``ERR: CRC failed``)."""

    text: str


@dataclass(frozen=True, slots=True)
class ParseError:
    """Bytes that looked like a frame but were not one: ``reason`` says why, ``data`` holds them."""

    reason: str
    data: bytes


Event = Frame | TextLine | ParseError


class Parser:
    """Streaming parser for the byte stream the board sends: frames, text lines, errors.

    ``feed(data)`` returns the events completed by these bytes. After a bad frame
    (bad CRC, impossible LEN) the parser drops only the START byte and rescans
    the rest, so a good frame hidden behind lost or garbled bytes is still found.
    Text bytes (printable ASCII, tab, CR) accumulate into a `TextLine` at each
    newline; other bytes outside frames are counted in ``garbage`` and dropped.
    """

    def __init__(self, max_text: int = 200) -> None:
        self._buf = bytearray()
        self._text = bytearray()
        self._max_text = max_text
        self.frames = 0
        """Good frames decoded."""
        self.crc_errors = 0
        self.length_errors = 0
        """Frames whose LEN was below 4 or above 10."""
        self.garbage = 0
        """Non-text bytes dropped outside frames."""

    def feed(self, data: bytes | bytearray) -> list[Event]:
        """Add received bytes; return the frames, text lines and errors they complete, in order."""
        self._buf += data
        events: list[Event] = []
        i = 0
        buf = self._buf
        while i < len(buf):
            byte = buf[i]
            if byte != START:
                self._text_byte(byte, events)
                i += 1
                continue
            if i + 1 >= len(buf):
                break                                  # need LEN
            length = buf[i + 1]
            if not MIN_LEN <= length <= MAX_LEN:
                self.length_errors += 1
                events.append(ParseError(f"bad frame length {length} (must be 4..10)",
                                         bytes(buf[i:i + 2])))
                i += 1                                 # rescan from the LEN byte
                continue
            if i + 1 + length > len(buf):
                break                                  # frame not complete yet
            body = bytes(buf[i + 1:i + length])        # LEN .. last payload byte
            if crc8(body) != buf[i + length]:
                self.crc_errors += 1
                events.append(ParseError("bad CRC", bytes(buf[i:i + 1 + length])))
                i += 1                                 # a real START may hide inside
                continue
            self.frames += 1
            events.append(Frame(body[1], body[2], body[3:]))
            i += 1 + length
        del buf[:i]
        return events

    def reset(self) -> None:
        """Forget a partial frame or text line (e.g. after a reply timeout on the host)."""
        self._buf.clear()
        self._text.clear()

    def _text_byte(self, byte: int, events: list[Event]) -> None:
        if byte == 0x0A:
            events.append(TextLine(self._text.decode("ascii")))
            self._text.clear()
        elif 0x20 <= byte < 0x7F or byte in (0x09, 0x0D):
            if len(self._text) >= self._max_text:     # a line that never ends must not grow forever
                events.append(TextLine(self._text.decode("ascii")))
                self._text.clear()
            self._text.append(byte)
        else:
            self.garbage += 1


# --------------------------------------------------------------------------- payloads


def pack_int8(value: int) -> bytes:
    """One signed byte; ValueError outside -128..127."""
    return _pack(">b", value, "int8")


def pack_uint8(value: int) -> bytes:
    return _pack(">B", value, "uint8")


def pack_int16(value: int) -> bytes:
    """Two bytes, big-endian signed; ValueError outside -32768..32767."""
    return _pack(">h", value, "int16")


def pack_uint16(value: int) -> bytes:
    return _pack(">H", value, "uint16")


def pack_float(value: float) -> bytes:
    """IEEE-754 single, big-endian (sign/exponent byte first)."""
    return struct.pack(">f", value)


def pack_multi_set(left: int, right: int) -> bytes:
    """MULTI_SET_VEL / MULTI_SET_VEL_GET_ENC payload: int8 RIGHT first, then int8 LEFT."""
    return pack_int8(right) + pack_int8(left)


def unpack_multi_set(payload: bytes) -> tuple[int, int]:
    """(left, right) from a MULTI set payload (which is right-first on the wire)."""
    right, left = struct.unpack(">bb", _exact(payload, 2))
    return left, right


def pack_multi_get(left: int, right: int) -> bytes:
    """MULTI_GET_ENC reply payload: int16 LEFT first, then int16 RIGHT."""
    return pack_int16(left) + pack_int16(right)


def unpack_multi_get(payload: bytes) -> tuple[int, int]:
    """(left, right) from a MULTI_GET_ENC / MULTI_SET_VEL_GET_ENC reply."""
    left, right = struct.unpack(">hh", _exact(payload, 4))
    return left, right


def unpack_int8(payload: bytes) -> int:
    return struct.unpack(">b", _exact(payload, 1))[0]


def unpack_uint8(payload: bytes) -> int:
    return _exact(payload, 1)[0]


def unpack_int16(payload: bytes) -> int:
    return struct.unpack(">h", _exact(payload, 2))[0]


def unpack_uint16(payload: bytes) -> int:
    return struct.unpack(">H", _exact(payload, 2))[0]


def unpack_float(payload: bytes) -> float:
    return struct.unpack(">f", _exact(payload, 4))[0]


def _pack(fmt: str, value: int, kind: str) -> bytes:
    try:
        return struct.pack(fmt, value)
    except struct.error:
        raise ValueError(f"{value!r} does not fit in {kind}") from None


def _exact(payload: bytes, size: int) -> bytes:
    if len(payload) != size:
        raise ValueError(f"expected a {size}-byte payload, got {len(payload)} bytes")
    return payload
