"""hwbridge's host side of the icoBoard against the shared protocol vectors (no processes).

The host must build exactly the vectors' request bytes and read the vectors'
replies as they are meant: counts into unbounded ticks, acks into lost frames,
status bits into board errors and watchdog warnings, a bad or stuck reply into
a CRC error. `IcoBoardBoard` is hwbridge's own board code; only its transport is
replaced by the vectors' replies.
"""

from __future__ import annotations

import msgspec
import pytest
from icoboard_vectors import SCENARIOS, Send

from icefloe import config as config_mod
from icefloe.errors import BoardError, BoardMismatch
from icefloe.services.hwbridge.icoboard import IcoBoardBoard
from icefloe.wire.icoboard import FrameError, Op, Wire

# What hwbridge must have counted after each scenario's replies.
EXPECTED = {
    # ticks count from the first reading (5, -3) on, and carry on across the final RESET
    "run": {"lost": 0, "board_errors": 0, "watchdog": 0, "ticks": (998, -1001)},
    "lost_frames": {"lost": 2, "board_errors": 2, "watchdog": 0, "ticks": (0, 0)},
    "bad_frames": {"lost": 1, "board_errors": 1, "watchdog": 0, "ticks": (0, 0), "not_running": 2},
    "watchdog": {"lost": 0, "board_errors": 0, "watchdog": 1, "ticks": (0, 0)},
}


def _board() -> IcoBoardBoard:
    config = config_mod.load(None)
    config = msgspec.structs.replace(config, board=msgspec.structs.replace(config.board, kind="icoboard"))
    return IcoBoardBoard(config, lambda kind, text: None)


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_hwbridge_builds_and_reads_the_shared_vectors(name: str) -> None:
    wire = Wire(2)
    board = _board()
    previous_seq = not_running = 0
    for step in SCENARIOS[name]:
        if not isinstance(step, Send):
            continue
        request = step.request
        try:
            parsed = wire.parse_request(request)
        except FrameError:
            parsed = None  # a frame the vector broke on purpose: the host never builds it
        if parsed is not None:
            assert wire.request(parsed.op, seq=parsed.seq, duties=parsed.duties) == request
        if step.reply is None:
            previous_seq = request[1]
            continue
        op = Op(request[0]) if request[0] <= max(Op) else Op.EMPTY
        if op == Op.START:
            wire.check_start(wire.parse_reply(Op.START, step.reply))
        elif op in (Op.RECEIVE, Op.TRANSMIT):
            try:
                board._reply(step.reply, previous_seq, 0)
            except BoardError as exc:  # hwbridge reopens the link (START) when it sees this
                assert "not running" in str(exc)
                not_running += 1
        elif op == Op.RESET and parsed is not None:
            for unwrap in board._unwrap:
                unwrap.rebase()  # as IcoBoardBoard.open does after its RESET
        previous_seq = request[1]
    expected = EXPECTED[name]
    assert (board.lost, board.board_errors, board.watchdog, (board.ticks_left, board.ticks_right),
            not_running) == (expected["lost"], expected["board_errors"], expected["watchdog"],
                             expected["ticks"], expected.get("not_running", 0))
    assert board.crc_errors == 0


def test_hwbridge_counts_stuck_and_corrupt_replies_as_crc_errors() -> None:
    board = _board()
    run = SCENARIOS["run"]
    first, later = run[3], run[8]  # RECEIVE with counts (5, -3), TRANSMIT with (1000, -1000)
    assert isinstance(first, Send) and isinstance(later, Send)
    board._reply(first.reply, 2, 0)
    good = later.reply
    for bad in (bytes(7), b"\xff" * 7, good[:3] + bytes([good[3] ^ 0x04]) + good[4:]):
        board._reply(bad, 4, 0)
    assert board.crc_errors == 3 and board.exchanges == 1
    board._reply(good, 4, 0)
    assert (board.ticks_left, board.ticks_right, board.exchanges) == (995, -997, 2)


def test_a_board_built_for_another_peripheral_list_is_refused() -> None:
    start = bytes.fromhex(SCENARIOS["run"][0].reply_hex)
    Wire(2).check_start(Wire(2).parse_reply(Op.START, start))
    with pytest.raises(BoardMismatch, match="peripheral hash"):
        Wire(2, sensors=2, actuators=3).check_start(Wire(2, 2, 3).parse_reply(Op.START, start))
