"""A stream that says only what changed, and now and then that nothing did: `Heartbeat`.

A pose stream of a robot standing still would repeat the same pose tens of times a second, each
one encoded, routed and decoded by every subscriber for nothing (issue 35: at rest). So odometry
and the localizer publish a pose when it changed, and otherwise at a low rate, the heartbeat:
enough that a subscriber waiting for a pose (the follower's ``pose_timeout_s``, a client's
``ready()``) still gets one in time.
"""

from __future__ import annotations


class Heartbeat:
    """Whether to publish now (`due`): at once when something changed, else every ``period_s``.

    ``slack_s``: how much earlier than a whole period a tick still counts as due: half the period
    of the loop that asks. A loop's ticks come a little early or late; without it, a heartbeat as
    fast as the loop would miss every tick that came early (half the rate, measured in
    tests/test_lab.py's 25 Hz poses). Times are seconds of any monotonic clock (a service's
    ``time.monotonic()``, a test's own)."""

    def __init__(self, period_s: float, slack_s: float = 0.0) -> None:
        self.period_s, self.slack_s = period_s, slack_s
        self._last: float | None = None
        self.beats = 0
        """Publications with nothing changed."""

    def due(self, changed: bool, now: float) -> bool:
        """True (and counted as published at ``now``) if ``changed``, or a period has passed since the last."""
        if changed or self._last is None or now - self._last >= self.period_s - self.slack_s:
            if not changed:
                self.beats += 1
            self._last = now
            return True
        return False
