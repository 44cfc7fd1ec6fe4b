"""Thin out a high-rate stream before it reaches the viewer.

hwbridge publishes ``hw/wheels`` at 50 Hz; a plot on a laptop screen gains
nothing from more than about 20 points a second, and every logged point costs
the viewer memory. `Decimator` keeps a message only when at least one period
has passed (by the message's own ``stamp``) since the last one it kept.

It works on stamps rather than on arrival times so that a burst of messages
that arrive together (Wi-Fi hiccup) is thinned by when they were *measured*,
and so that it can be tested without a clock.
"""

from __future__ import annotations


class Decimator:
    """Keep at most ``rate_hz`` messages per second of stamp time (``rate_hz <= 0``: keep all)."""

    def __init__(self, rate_hz: float) -> None:
        self.period_ns = int(1e9 / rate_hz) if rate_hz > 0 else 0
        self.kept = 0
        self.dropped = 0
        self._last: int | None = None

    def keep(self, stamp: int) -> bool:
        """True if the message stamped ``stamp`` (ns) should go to the viewer."""
        last = self._last
        # A stamp that goes backwards means the robot restarted or its clock was set:
        # start again from here instead of going quiet until time catches up.
        if last is None or stamp < last or stamp - last >= self.period_ns:
            self._last = stamp
            self.kept += 1
            return True
        self.dropped += 1
        return False
