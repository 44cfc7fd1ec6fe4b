"""The PenguinPi's shutdown lines between the Pi, the board and the SDN button.

On the real robot (penguinpi-facts §3.8 and §7; BCM numbering):

=======  ==========================  ===============  =======================================
GPIO     wire                        driven by        meaning
=======  ==========================  ===============  =======================================
22       SDN push-button             the button       low = pressed (pull-up, active low)
10       Atmel PB5 (MOSI)            the board        low = "please shut down" (low battery)
11       Atmel PB7 (SCLK)            the Pi           high = shutdown daemon alive; falling
                                                      after high = the Pi is shutting down
=======  ==========================  ===============  =======================================

`GpioLines` holds the level (1 high, 0 low) of each line, with the handles a
test or the ``sim/control`` queryable uses: press, hold and release the button,
pull the request line, and set the acknowledge line as the Pi would. The board
model reads `ack` (and `ack_fell`) and drives `request`; time comes in through
`tick`, so a held button releases exactly on time.

Thread-safe: the simulator's clock, the board's I/O thread and the bus handler
all use it.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

BUTTON = 22
"""SDN button, input with pull-up, active low."""
REQUEST = 10
"""Board -> Pi shutdown request (PB5), input with pull-up, active low."""
ACK = 11
"""Pi -> board "daemon alive" (PB7), output; high while the daemon runs."""
LINES = (BUTTON, REQUEST, ACK)


class GpioLines:
    """Levels of the three shutdown lines, with test handles."""

    def __init__(self, request_source: Callable[[], bool] | None = None,
                 on_change: Callable[[int, int], None] | None = None) -> None:
        """``request_source``: returns True while the board pulls GPIO10 low (e.g. the
        PenguinPi model's PB5); None = only the `pull_request` handle drives it.
        ``on_change(line, level)``: called (on the thread that made the change) for
        every level change of every line, e.g. to publish it on ``sim/gpio``."""
        self._lock = threading.Lock()
        self._request_source = request_source
        self.on_change = on_change
        self._published = {BUTTON: 1, REQUEST: 1, ACK: 0}
        self._button_down = False
        self._release_at: float | None = None
        self._request_forced = False
        self._ack = 0  # the Pi has not driven GPIO11 high yet: the pull-down reads 0
        self._ack_seen_high = False
        self._now = 0.0
        self.presses = 0
        """Button presses since start."""

    # ------------------------------------------------------------------ handles

    def press(self) -> None:
        """Push the SDN button down (it stays down until `release`)."""
        with self._lock:
            if not self._button_down:
                self.presses += 1
            self._button_down, self._release_at = True, None
        self._changed()

    def hold(self, seconds: float) -> None:
        """Push the button and let go ``seconds`` of simulated time later."""
        if not seconds >= 0:
            raise ValueError(f"hold time must be >= 0 s, got {seconds}")
        self.press()
        with self._lock:
            self._release_at = self._now + seconds

    def release(self) -> None:
        """Let go of the button."""
        with self._lock:
            self._button_down, self._release_at = False, None
        self._changed()

    def pull_request(self, low: bool) -> None:
        """Drive GPIO10 low (True) or let it go (False), as the board does on low battery."""
        with self._lock:
            self._request_forced = low
        self._changed()

    def set_ack(self, level: int) -> None:
        """Drive GPIO11 as the Pi's shutdown daemon does: 1 while alive, 0 when shutting down."""
        if level not in (0, 1):
            raise ValueError(f"GPIO{ACK} level must be 0 or 1, got {level}")
        with self._lock:
            self._ack = level
            self._ack_seen_high |= level == 1
        self._changed()

    def set(self, line: int, level: int) -> None:
        """Set a line by number: 22 low = press, 10 low = request, 11 = acknowledge."""
        if level not in (0, 1):
            raise ValueError(f"GPIO{line} level must be 0 or 1, got {level}")
        if line == BUTTON:
            if level == 0:
                self.press()
            else:
                self.release()
        elif line == REQUEST:
            self.pull_request(level == 0)
        elif line == ACK:
            self.set_ack(level)
        else:
            raise ValueError(f"GPIO{line} is not simulated (lines: {', '.join(map(str, LINES))})")

    # ------------------------------------------------------------------ the clock

    def tick(self, now: float) -> None:
        """Called by the simulator's clock with simulated time, s."""
        with self._lock:
            self._now = now
            if self._release_at is not None and now >= self._release_at:
                self._button_down, self._release_at = False, None
        self._changed()  # also catches the board's request line changing

    def _changed(self) -> None:
        """Report each line whose level differs from the last one reported."""
        for line, level in self.levels().items():
            with self._lock:
                if self._published[line] == level:
                    continue
                self._published[line] = level
            if self.on_change is not None:
                self.on_change(line, level)

    # ------------------------------------------------------------------ levels

    @property
    def button(self) -> int:
        """GPIO22 level: 0 while the button is down."""
        with self._lock:
            return 0 if self._button_down else 1

    @property
    def request(self) -> int:
        """GPIO10 level: 0 while the board asks the Pi to shut down."""
        source = self._request_source
        pulled = source() if source is not None else False
        with self._lock:
            return 0 if (pulled or self._request_forced) else 1

    @property
    def ack(self) -> int:
        """GPIO11 level as the board reads it."""
        with self._lock:
            return self._ack

    @property
    def ack_fell(self) -> bool:
        """True once GPIO11 has been high and is now low: the Pi is shutting down (§3.8)."""
        with self._lock:
            return self._ack_seen_high and self._ack == 0

    def levels(self) -> dict[int, int]:
        """{line: level} of every simulated line."""
        return {BUTTON: self.button, REQUEST: self.request, ACK: self.ack}
