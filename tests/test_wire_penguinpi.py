"""The PenguinPi wire protocol: CRC, frames, the streaming parser, payload helpers (facts §1)."""

from __future__ import annotations

import random

import pytest

from icefloe.wire import penguinpi as w

# The facts' test-vector table (§1.3): (address, opcode, payload, full frame hex).
VECTORS = [
    (0x13, 0x81, "", "11 04 13 81 56"),
    (0x12, 0x82, "", "11 04 12 82 01"),
    (0x12, 0x01, "00 32", "11 06 12 01 00 32 84"),
    (0x11, 0x01, "FF CE", "11 06 11 01 FF CE DB"),
    (0x13, 0x82, "14 EC", "11 06 13 82 14 EC E7"),
    (0x31, 0x02, "C8", "11 05 31 02 C8 4C"),
    (0x60, 0x12, "01", "11 05 60 12 01 4C"),
    (0x60, 0x11, "C0 A8 01 0A", "11 08 60 11 C0 A8 01 0A 49"),
    (0x60, 0x14, "B8 27 EB 01 02 03", "11 0A 60 14 B8 27 EB 01 02 03 88"),
    (0x41, 0x02, "3F 73 33 33", "11 08 41 02 3F 73 33 33 25"),
    (0x12, 0x82, "04 D2", "11 06 12 82 04 D2 32"),
    (0x13, 0x81, "00 64 FF FB", "11 08 13 81 00 64 FF FB D1"),
    (0x41, 0x84, "45 E7 40 00", "11 08 41 84 45 E7 40 00 FE"),
    (0x60, 0xA0, "01", "11 05 60 A0 01 25"),
]


def test_crc_check_value() -> None:
    assert w.crc8(b"123456789") == 0xC2


@pytest.mark.parametrize(("address", "opcode", "payload", "frame"), VECTORS)
def test_vectors_encode(address: int, opcode: int, payload: str, frame: str) -> None:
    assert w.encode_frame(address, opcode, bytes.fromhex(payload)) == bytes.fromhex(frame)


@pytest.mark.parametrize(("address", "opcode", "payload", "frame"), VECTORS)
def test_vectors_decode(address: int, opcode: int, payload: str, frame: str) -> None:
    parser = w.Parser()
    assert parser.feed(bytes.fromhex(frame)) == [w.Frame(address, opcode, bytes.fromhex(payload))]
    # Running the CRC over the body and its CRC gives zero (facts §1.3).
    assert w.crc8(bytes.fromhex(frame)[1:]) == 0


def test_vector_values_through_helpers() -> None:
    assert w.pack_int16(50) == bytes.fromhex("00 32")
    assert w.pack_int16(-50) == bytes.fromhex("FF CE")
    assert w.pack_multi_set(left=-20, right=20) == bytes.fromhex("14 EC")
    assert w.unpack_multi_set(bytes.fromhex("14 EC")) == (-20, 20)
    assert w.unpack_multi_get(bytes.fromhex("00 64 FF FB")) == (100, -5)
    assert w.pack_multi_get(100, -5) == bytes.fromhex("00 64 FF FB")
    assert w.unpack_float(bytes.fromhex("45 E7 40 00")) == 7400.0
    assert w.pack_float(0.95) == bytes.fromhex("3F 73 33 33")
    assert w.unpack_int16(bytes.fromhex("04 D2")) == 1234
    assert w.unpack_uint16(bytes.fromhex("FF FF")) == 0xFFFF
    assert w.unpack_uint8(b"\x01") == 1
    assert w.unpack_int8(b"\xff") == -1


def test_pack_rejects_out_of_range() -> None:
    with pytest.raises(ValueError, match="int8"):
        w.pack_int8(128)
    with pytest.raises(ValueError, match="int16"):
        w.pack_int16(40000)
    with pytest.raises(ValueError, match="2-byte payload"):
        w.unpack_int16(b"\x00")


def test_encode_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="payload must be at most 6"):
        w.encode_frame(0x60, 0x14, bytes(7))
    with pytest.raises(ValueError, match="address"):
        w.encode_frame(256, 0x01)
    with pytest.raises(ValueError, match="opcode"):
        w.encode_frame(0x12, -1)


def test_parser_byte_at_a_time_and_text_lines() -> None:
    parser = w.Parser()
    stream = b"ERR: CRC failed\nDBG: DG: 05 12 01 00 32 \n" + bytes.fromhex("11 06 12 82 04 D2 32")
    events = [e for b in stream for e in parser.feed(bytes([b]))]
    assert events == [w.TextLine("ERR: CRC failed"), w.TextLine("DBG: DG: 05 12 01 00 32 "),
                      w.Frame(0x12, 0x82, bytes.fromhex("04 D2"))]


def test_parser_resyncs_after_bad_crc_and_lost_bytes() -> None:
    good = bytes.fromhex("11 08 13 81 00 64 FF FB D1")
    parser = w.Parser()
    # A frame with its last two bytes lost, immediately followed by a good one:
    # the first frame's LEN swallows part of the second, the CRC fails, and the
    # parser must still find the second frame.
    events = parser.feed(good[:-2] + good)
    assert isinstance(events[0], w.ParseError) and events[0].reason == "bad CRC"
    assert events[-1] == w.Frame(0x13, 0x81, bytes.fromhex("00 64 FF FB"))
    assert parser.crc_errors == 1 and parser.frames == 1


def test_parser_rejects_impossible_length_and_finds_next_frame() -> None:
    parser = w.Parser()
    events = parser.feed(b"\x11\x20" + bytes.fromhex("11 05 60 A0 01 25"))
    assert isinstance(events[0], w.ParseError) and "length 32" in events[0].reason
    assert events[-1] == w.Frame(0x60, 0xA0, b"\x01")
    assert parser.length_errors == 1


def test_parser_survives_random_garbage() -> None:
    rng = random.Random(7)
    frames = [w.encode_frame(0x12, 0x82, w.pack_int16(rng.randrange(-32768, 32768)))
              for _ in range(50)]
    parser = w.Parser()
    found = []
    for frame in frames:
        garbage = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 12)))
        # Garbage without START bytes can never hide a frame: each frame must be recovered.
        garbage = garbage.replace(b"\x11", b"\x12")
        found += [e for e in parser.feed(garbage + frame) if isinstance(e, w.Frame)]
    assert [w.encode_frame(f.address, f.opcode, f.payload) for f in found] == frames


def test_parser_reset_drops_partial_frame() -> None:
    parser = w.Parser()
    assert parser.feed(b"\x11\x06\x12") == []
    parser.reset()
    assert parser.feed(bytes.fromhex("11 04 12 82 01")) == [w.Frame(0x12, 0x82)]


def test_op_tables_cover_every_opcode() -> None:
    assert set(w.MOTOR_OPS) == {int(op) for op in w.MotorOp}
    assert set(w.MULTI_OPS) == {int(op) for op in w.MultiOp}
    assert set(w.LED_OPS) == {int(op) for op in w.LedOp}
    assert set(w.ADC_OPS) == {int(op) for op in w.AdcOp}
    assert set(w.HAT_OPS) == {int(op) for op in w.HatOp}
    for table in (w.MOTOR_OPS, w.MULTI_OPS, w.LED_OPS, w.ADC_OPS, w.HAT_OPS):
        for opcode, spec in table.items():
            assert (spec.reply is not None) == bool(opcode & w.GET_BIT), spec.name
