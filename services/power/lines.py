"""Debouncing an active-low input line and deciding when it was held long enough.

Pure logic with the clock passed in, so tests can replay edges at exact times.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class HoldDetector:
    """One active-low line (a push-button or a request line) that counts when held low.

    * A *bounce burst*: edges closer together than ``debounce_s``. The line is
      only trusted once it has not changed for ``debounce_s``.
    * A *press*: the line low for ``hold_s`` since its last edge. It counts once;
      the detector re-arms only after the line has been stably high again, so a
      burst of toggles (at the start, the middle or the end of a press) is still
      one press.

    Times are seconds on any clock, as long as `edge` and `poll` use the same one.
    """

    hold_s: float
    """How long the line must stay low, s."""
    debounce_s: float = 0.02
    """Edges closer together than this are one burst, s."""

    level: int = 1
    """Last level seen (1 = released: the lines have pull-ups)."""
    last_edge: float = float("-inf")
    """Time of the last edge, s."""
    presses: int = 0
    """Presses counted so far."""
    settled: int = 1
    """The level last reported by `settled_change`."""
    _armed: bool = True

    def edge(self, level: int, t: float) -> None:
        """The line changed to ``level`` (0 or 1) at time ``t`` (s)."""
        if level not in (0, 1):
            raise ValueError(f"a line level is 0 or 1, got {level!r}")
        if level != self.level:
            self.level, self.last_edge = level, t

    def poll(self, now: float) -> bool:
        """True exactly once per press, at the first poll after it was held ``hold_s``."""
        quiet = now - self.last_edge
        if self.level == 1:
            if quiet >= self.debounce_s:
                self._armed = True
            return False
        if self._armed and quiet >= max(self.hold_s, self.debounce_s):
            self._armed = False
            self.presses += 1
            return True
        return False

    @property
    def idle(self) -> bool:
        """Nothing will change before the next edge: `poll` and `settled_change` would return
        nothing and change nothing (released and re-armed, or held and its press counted)."""
        return self.level == self.settled and self._armed == (self.level == 1)

    def settled_change(self, now: float) -> int | None:
        """The line's new level once it has kept it for ``debounce_s`` (0: pressed, 1: released),
        reported once per change; None while it bounces or has not changed."""
        if self.level != self.settled and now - self.last_edge >= self.debounce_s:
            self.settled = self.level
            return self.settled
        return None
