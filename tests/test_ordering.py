"""Which motion commands may drive after a stop: `ordering.CommandOrder`, with exact times.

Times are CLOCK_MONOTONIC ns on hwbridge's side and each sender's own clock on the
other; a laptop's clock is seconds off the robot's in both directions here.
"""

from __future__ import annotations

import random

import pytest

from icefloe.ordering import DRIFT, MAX_SENDERS, CommandOrder, Origin

MS = 1_000_000
S = 1_000_000_000
DEADMAN = 500 * MS


class Sender:
    """A program sending numbered, stamped commands on a clock ``offset`` ns off the robot's."""

    def __init__(self, name: str, offset: int = 0, latency: int = 2 * MS) -> None:
        self.name, self.offset, self.latency, self.seq = name, offset, latency, 0

    def send(self, issued: int, delay: int = 0) -> Origin:
        """A command issued at robot time ``issued``, arriving ``latency + delay`` later."""
        self.seq += 1
        return Origin.of(issued + self.latency + delay, self.name, self.seq, issued + self.offset)


@pytest.mark.parametrize("offset", [0, 5 * S, -5 * S, 3600 * S], ids=["same", "ahead", "behind", "hour"])
def test_a_motion_issued_before_a_stop_never_drives(offset: int) -> None:
    order = CommandOrder(DEADMAN)
    laptop, webapi = Sender("laptop", offset, latency=3 * MS), Sender("webapi", 0, latency=MS // 2)
    t = 10 * S
    for i in range(20):  # the laptop drives at 20 Hz: hwbridge learns its clock
        assert order.motion(laptop.send(t + i * 50 * MS)) [1] == ""
    t += 20 * 50 * MS
    # Same sender: the hold's last command and the stop right after it, at a higher priority:
    # the stop arrives first, the command 4 ms later.
    late_motion = laptop.send(t, delay=4 * MS)
    order.stop(laptop.send(t + MS // 10), 1)
    assert "same sender" in order.motion(late_motion)[1]
    assert order.motion(laptop.send(t + 100 * MS))[1] == ""      # issued after: drives
    # Another sender's stop: a laptop command issued 10 ms before it, held 60 ms on Wi-Fi.
    t += 200 * MS
    held = laptop.send(t - 10 * MS, delay=60 * MS)
    order.stop(webapi.send(t), 2)
    assert "before the latest stop" in order.motion(held)[1]
    assert order.motion(laptop.send(t + 5 * MS))[1] == ""        # issued after it: drives


def test_commands_older_than_the_deadman_never_drive_whatever_the_clocks() -> None:
    order = CommandOrder(DEADMAN)
    laptop = Sender("laptop", offset=-7 * S)
    t = 100 * S
    for i in range(20):
        assert order.motion(laptop.send(t + i * 50 * MS))[1] == ""
    # hwbridge's bus side stalls 2 s while the laptop sends for 0.5 s more, then goes silent:
    # everything comes out at once after the stall.
    t += 20 * 50 * MS
    stall_end = t + 2 * S
    backlog = [laptop.send(t + i * 50 * MS, delay=stall_end - (t + i * 50 * MS)) for i in range(10)]
    verdicts = [order.motion(o)[1] for o in backlog]
    assert all("older than the deadman" in v for v in verdicts), verdicts
    # A command issued 0.3 s before it arrived still drives, for what is left of the deadman.
    # Its age is known to within the fastest delivery (2 ms) plus what the offset may rise over
    # the 2 s stall (2 ms, `DRIFT`).
    issued, why = order.motion(laptop.send(stall_end - 300 * MS, delay=298 * MS))
    assert why == "" and 295 * MS <= stall_end - issued <= 300 * MS


def test_a_sender_clock_drifting_over_an_hour_is_followed() -> None:
    order = CommandOrder(DEADMAN)
    rng = random.Random(1)
    issued_ages = []
    t, skew = 0, -2 * S
    for _ in range(72_000):  # 20 Hz for an hour, the sender's clock 200 ppm slow, 1-5 ms delivery
        t += 50 * MS
        latency = rng.randint(1 * MS, 5 * MS)
        o = Origin.of(t + latency, "laptop", 0, t + skew - int(t * 200e-6))
        issued, why = order.motion(o)
        assert why == ""
        issued_ages.append(o.arrival_ns - issued)
    assert max(issued_ages[100:]) < 5 * MS  # the age is the delay beyond the fastest delivery
    assert DRIFT * 1e6 > 200  # ppm the offset may follow


def test_a_repeated_stop_is_the_same_stop_and_a_late_stop_still_stops() -> None:
    order = CommandOrder(DEADMAN)
    client = Sender("client")
    stop = client.send(S)
    assert order.stop(stop, 1)[1] == 1
    assert order.stop(stop, 2)[1] == 1                  # cmd/halt repeating cmd/stop's seq
    newer = client.send(2 * S)
    assert order.motion(newer)[1] == ""
    late_stop = Origin.of(3 * S, "client", stop.seq - 1 if stop.seq > 1 else 0, S)
    assert order.stop(late_stop, 3)[1] == 3             # a stop is never refused


def test_commands_without_the_fields() -> None:
    """No sender, seq or stamp (a student's JSON): the router's Zenoh timestamp orders them,
    else the arrival at hwbridge."""
    order = CommandOrder(DEADMAN)
    router = "4a1f"
    for i in range(10):
        assert order.motion(Origin.of(S + i * 50 * MS + MS, zenoh_id=router,
                                      zenoh_ns=S + i * 50 * MS))[1] == ""
    t = 2 * S
    order.stop(Origin.of(t + MS, zenoh_id=router, zenoh_ns=t), 1)
    # Stamped by the router before the stop, delivered to hwbridge after it: refused.
    assert order.motion(Origin.of(t + 3 * MS, zenoh_id=router, zenoh_ns=t - MS))[1] != ""
    assert order.motion(Origin.of(t + 5 * MS, zenoh_id=router, zenoh_ns=t + 3 * MS))[1] == ""
    # Without any clock: whatever arrives after the stop drives.
    order.stop(Origin(3 * S), 2)
    assert order.motion(Origin(3 * S + 1))[1] == ""


def test_the_latest_stop_of_another_sender_counts_not_ones_own() -> None:
    order = CommandOrder(DEADMAN)
    a, b = Sender("a"), Sender("b")
    order.stop(b.send(S), 1)
    order.stop(a.send(2 * S), 2)
    # a's own stop is ordered by seq; b's stop (issued earlier) is what its time is held against.
    assert order.motion(a.send(S + 500 * MS))[1] == ""
    assert order.motion(b.send(S + 500 * MS))[1] != ""   # b's motion is older than a's stop
    assert order.latest_stop() == 2 * S + 2 * MS
    assert order.latest_stop(excluding="a") == S + 2 * MS


def test_memory_stays_bounded_whatever_the_senders() -> None:
    order = CommandOrder(DEADMAN)
    for i in range(10_000):
        o = Origin.of(S + i, f"s{i}", 1, 123 + i)
        order.motion(o) if i % 2 else order.stop(o, i)
    assert order.remembered <= 2 * MAX_SENDERS


def test_a_sender_restarted_under_the_same_name_drives_again() -> None:
    """A student's program with a fixed ``sender`` numbers from 1 again after a restart: its
    stamps, later than any before, say so (a command issued earlier never does)."""
    order = CommandOrder(DEADMAN)
    first = Sender("my-robot-script")
    for i in range(10):
        assert order.motion(first.send(S + i * 50 * MS))[1] == ""
    order.stop(first.send(2 * S), 1)
    again = Sender("my-robot-script")                  # seq from 1 again
    assert order.motion(again.send(5 * S))[1] == ""
    # Still exact for reordering: a command issued before that restart's stop stays refused.
    held = again.send(6 * S, delay=10 * MS)
    order.stop(again.send(6 * S + MS), 2)
    assert "same sender" in order.motion(held)[1]
