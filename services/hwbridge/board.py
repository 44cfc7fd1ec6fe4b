"""What the real-time cycle sees of a board: one small interface, two backends.

`Board` is the base class of `penguinpi.PenguinPiBoard` and
`icoboard.IcoBoardBoard`. The cycle calls `open` (and again after the link
was lost), then `cycle` once per period with the wheel targets, `io` for a
queued LED/text/screen command, and `stop` + `close` at the end. Each backend
fills in the readings below; the cycle copies them into shared memory.

`make_board` picks the backend named by ``board.kind`` and, for the transport,
``board.backend`` (hardware or sim): the cycle cannot tell which one it drives.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from icefloe.config import RobotConfig

from .shm import MSG_BOARD, MSG_ERROR, MSG_INFO, MSG_WARNING

Say = Callable[[int, str], None]
"""How a backend reports a line: ``say(kind, text)`` with a `shm.MSG_*` kind."""

__all__ = ["MSG_BOARD", "MSG_ERROR", "MSG_INFO", "MSG_WARNING", "Board", "Say", "make_board"]


class Board:
    """Readings and counters every backend keeps up to date (the cycle reads them)."""

    name = "board"

    def __init__(self, config: RobotConfig, say: Say) -> None:
        self.config = config
        self.say = say
        self.clock: Callable[[], int] = time.monotonic_ns
        """CLOCK_MONOTONIC now, ns: when a reply arrived (tests give the simulated time)."""
        # encoder sample
        self.sample_ns = 0
        """CLOCK_MONOTONIC time of the latest encoder sample, ns (0 = none yet)."""
        self.stamp = 0
        """The same instant, ns since the Unix epoch."""
        self.ticks_left = 0
        """Unbounded encoder counts (`control.Unwrapper`)."""
        self.ticks_right = 0
        self.speed_left = 0.0
        """Measured rim speed, m/s."""
        self.speed_right = 0.0
        self.duty_left = 0.0
        """What the board is told: duty fraction (icoBoard) or demand units (PenguinPi)."""
        self.duty_right = 0.0
        self.exchanges = 0
        """Completed wheel exchanges (icoBoard: SPI frames; PenguinPi: MULTI replies)."""
        # link errors, since start
        self.crc_errors = 0
        self.timeouts = 0
        """Requests that got no reply in time."""
        self.unmatched = 0
        """Good frames that answered nothing we asked (late replies, duplicates)."""
        self.garbage_bytes = 0
        """Bytes that were neither a frame nor text (or frames of the wrong length)."""
        self.board_errors = 0
        """Errors the board itself reported (PenguinPi ``ERR:`` lines, icoBoard REJECTED)."""
        self.lost = 0
        """icoBoard v2: frames the board did not acknowledge."""
        self.late = 0
        """icoBoard: replies that came after their cycle had given up on them."""
        self.watchdog = 0
        """icoBoard v2: times the board's watchdog stopped the wheels."""
        self.stop_confirmed = False
        """True while the board is verified in its stopped state: zero duty, controller state
        cleared (what "verified" means is up to each backend; see docs/hwbridge.md)."""
        # board readings
        self.battery_voltage = 0.0
        """V (0 = not read yet)."""
        self.battery_current = 0.0
        """A."""
        self.battery_ns = 0
        self.button_presses = 0
        """User button (PenguinPi S4) presses since start."""
        self.dip = -1
        """DIP switch value 0..15 (-1 = not read yet)."""
        self.rest_period_ns = 0
        """The cycle's period while it rests (`control.RestGate`), ns; 0 while it is awake. A
        backend that has more to ask than one exchange per period shares them out by it."""

    def open(self, now_ns: int) -> None:
        """Connect and handshake; raises `BoardError` (retried) or `BoardMismatch` (fatal)."""
        raise NotImplementedError

    def cycle(self, now_ns: int, left: float, right: float, stopped: bool, until_ns: int = 0) -> None:
        """One period: targets (rim speeds, m/s) out, readings in. Never waits on the link.

        ``stopped`` means the targets are zero (a stop, the deadman, no command yet, or
        a command of zero speed): the backend drives zero duty without any controller
        action, clears the controller's state, and sets `stop_confirmed` once the board
        has shown it did.
        ``until_ns`` (CLOCK_MONOTONIC), when given, is when to stop waiting for a
        reply (a stop sent between periods must not delay the next period).
        Raises `BoardError` when the link is lost.
        """
        raise NotImplementedError

    def io(self, kind: int, a: int, b: int, data: bytes) -> None:
        """Queue an LED / LED array / screen / text command (`shm.IO_*`)."""

    def stop(self) -> None:
        """Tell the board to stop the wheels now and leave it stopped, controller cleared, when
        this process is gone (on exit and when the link is lost; best effort, never raises,
        never waits long)."""

    def stop_lost(self) -> None:
        """The link was lost: stop the wheels like `stop`, but leave what the board counted
        for the reconnect where it can (the icoBoard v2 keeps running; default: `stop`)."""
        self.stop()

    def close(self) -> None:
        """Release the link (idempotent)."""


def make_board(config: RobotConfig, say: Say) -> Board:
    """The backend for ``config.board.kind``."""
    if config.board.kind == "icoboard":
        from .icoboard import IcoBoardBoard

        return IcoBoardBoard(config, say)
    from .penguinpi import PenguinPiBoard

    return PenguinPiBoard(config, say)
