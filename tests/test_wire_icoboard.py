"""The icoBoard SPI frames: thesis v1 byte for byte, and our v2 with seq and CRC-8."""

from __future__ import annotations

import pytest

from icefloe.errors import BoardMismatch
from icefloe.wire.icoboard import (
    BadCrc,
    BadLength,
    Descriptor,
    Op,
    Reply,
    SequenceGap,
    Status,
    UnexpectedOpcode,
    Wire,
    check_ack,
    check_sequence,
    crc8,
    delta16,
    duty_to_raw,
    raw_to_duty,
)


def test_crc8_is_autosar_and_catches_stuck_lines() -> None:
    assert crc8(b"123456789") == 0xDF  # the catalogue check value of CRC-8/AUTOSAR
    for length in (3, 7, 10):
        for stuck in (0x00, 0xFF):
            frame = bytes([stuck] * length)
            assert crc8(frame[:-1]) != frame[-1], f"stuck 0x{stuck:02x} line passes at {length} B"


def test_v1_lengths_follow_table_4_2() -> None:
    wire = Wire(1, sensors=2, actuators=2)
    assert [wire.length(op) for op in Op] == [1, 1, 5, 5, 1, 1]
    wide = Wire(1, sensors=3, actuators=1)
    assert wide.length(Op.RECEIVE) == 1 + 2 * 3
    assert wide.length(Op.TRANSMIT) == 1 + 2 * 3  # 1 + B*max(M, N)


def test_v1_host_frames_are_exact_bytes() -> None:
    wire = Wire(1)
    assert wire.request(Op.START) == b"\x01"
    assert wire.request(Op.RECEIVE) == b"\x02\x00\x00\x00\x00"
    assert wire.request(Op.TRANSMIT, duties=[32767, -1]) == b"\x03\x7f\xff\xff\xff"
    assert wire.request(Op.EXIT) == b"\x04"
    assert wire.request(Op.RESET) == b"\x05"


def test_v1_board_reply_and_host_parse() -> None:
    wire = Wire(1)
    assert wire.reply(Op.START, 1, head=2) == b"\x02"  # START reply is M
    frame = wire.reply(Op.TRANSMIT, 5, head=Op.TRANSMIT, counts=[65537, -1])
    assert frame == b"\x03\x00\x01\xff\xff"  # counts are 16-bit and wrap
    assert wire.parse_reply(Op.TRANSMIT, frame) == Reply(3, counts=(1, 65535))
    wire.check_start(wire.parse_reply(Op.START, b"\x02"))
    with pytest.raises(BoardMismatch, match="M = 3 sensors, config says 2"):
        wire.check_start(wire.parse_reply(Op.START, b"\x03"))


def test_v1_transmit_pads_actuators_to_max_m_n() -> None:
    wire = Wire(1, sensors=3, actuators=1)
    frame = wire.request(Op.TRANSMIT, duties=[-2])
    assert frame == b"\x03\xff\xfe\x00\x00\x00\x00"
    assert wire.parse_request(frame).duties == (-2,)


def test_v2_round_trip_both_sides() -> None:
    wire = Wire(2)
    frame = wire.request(Op.TRANSMIT, seq=257, duties=[1000, -1000])
    assert len(frame) == 2 + 4 + 1 and frame[1] == 1  # seq wraps at 256
    request = wire.parse_request(frame)
    assert request.op == Op.TRANSMIT and request.seq == 1 and request.duties == (1000, -1000)
    reply = wire.reply(Op.TRANSMIT, len(frame), head=Status.RUNNING, ack=0, counts=[5, -5])
    parsed = wire.parse_reply(Op.TRANSMIT, reply)
    assert parsed == Reply(Status.RUNNING, 0, counts=(5, 65531))
    check_ack(0, parsed)
    with pytest.raises(SequenceGap, match="acknowledged seq 0, we sent 1"):
        check_ack(1, parsed)


def test_v2_start_descriptor_and_mismatch() -> None:
    wire = Wire(2)
    frame = wire.request(Op.START, seq=0)
    assert len(frame) == 10
    reply = wire.parse_reply(Op.START, wire.reply(Op.START, 10, head=0, ack=255))
    assert reply.descriptor == Descriptor.of(2, 2) and reply.ack == 255
    wire.check_start(reply)
    other = Wire(2, sensors=3, actuators=2)
    with pytest.raises(BoardMismatch, match=r"sensors M = 3 \(config says 2\).*peripheral hash"):
        wire.check_start(other.parse_reply(Op.START, other.reply(Op.START, 10, head=0)))


def test_v2_every_single_bit_flip_is_caught() -> None:
    wire = Wire(2)
    frame = wire.request(Op.TRANSMIT, seq=7, duties=[123, -456])
    for bit in range(len(frame) * 8):
        bad = bytearray(frame)
        bad[bit // 8] ^= 1 << (bit % 8)
        with pytest.raises((BadCrc, UnexpectedOpcode, BadLength)):
            wire.parse_request(bytes(bad))


def test_named_errors_for_bad_frames() -> None:
    wire = Wire(2)
    with pytest.raises(BadLength, match="v2 TRANSMIT request: 6 bytes, expected 7"):
        wire.parse_request(wire.request(Op.TRANSMIT, duties=[0, 0])[:-1])
    with pytest.raises(UnexpectedOpcode, match="unknown opcode 9"):
        wire.parse_request(b"\x09\x00\x00")
    with pytest.raises(BadLength, match="empty"):
        wire.parse_request(b"")
    good = wire.reply(Op.RECEIVE, 7, head=1, counts=[1, 2])
    with pytest.raises(BadCrc, match="v2 reply"):
        wire.parse_reply(Op.RECEIVE, good[:-1] + bytes([good[-1] ^ 0x10]))
    with pytest.raises(ValueError, match="TRANSMIT takes 2 duties"):
        wire.request(Op.TRANSMIT, duties=[1])


def test_reply_to_a_frame_of_the_wrong_length_is_head_and_zeros() -> None:
    assert Wire(2).reply(Op.TRANSMIT, 4, head=5, ack=9, counts=[1, 1]) == b"\x05\x00\x00\x00"


def test_sequence_and_value_helpers() -> None:
    check_sequence(0, 256)  # compared mod 256
    with pytest.raises(SequenceGap, match="2 frame"):
        check_sequence(10, 12)
    assert delta16(3, 65533) == 6 and delta16(65533, 3) == -6
    assert duty_to_raw(2.0) == 32767 and duty_to_raw(-0.5) == -16384
    assert raw_to_duty(-32768) == -1.0 and raw_to_duty(32767) == 1.0
    with pytest.raises(ValueError, match="version must be 1 or 2"):
        Wire(3)


def test_v1_start_to_a_board_still_running_says_so() -> None:
    wire = Wire(1)
    with pytest.raises(BoardMismatch, match=r"still running .* send EXIT before START"):
        wire.check_start(wire.parse_reply(Op.START, b"\x03"))
