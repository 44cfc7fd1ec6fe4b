"""Which motion commands may still drive: the order of commands and stops, and their age.

hwbridge applies these rules to every motion command; the path follower applies them to paths
(``nav/path``), so a stop wins there too.

Zenoh keeps one queue per priority, so a motion command sent just before a
stop can arrive after it (``cmd/stop`` travels at real-time priority), and a
stalled process or network delivers old commands late. hwbridge therefore
orders commands by what they carry, not by when they arrive:

* ``sender`` + ``seq``: one sender's commands and stops, in the order it issued
  them, exactly, whatever their priority or encoding (the client library, the
  web API and the examples number every command).
* ``sender`` + ``stamp``: when the command was issued, on the sender's clock.
  Clocks differ (a laptop can be seconds off the robot), so each sender's clock
  is mapped onto hwbridge's own: `SenderClock` keeps the smallest ``arrival -
  stamp`` seen, which is the clock offset plus the fastest delivery. A
  command's *issue time* is then ``stamp + offset`` on hwbridge's clock, its
  *age* the delay beyond the fastest delivery: a stall shows up as age, a
  clock offset does not.
* Neither: the Zenoh timestamp the robot's router put on the sample on its way
  in (mapped the same way, one clock per timestamping router), or, without
  one, the time hwbridge received it.

The rules (`CommandOrder`):

1. A stop is never refused: even a late one stops the wheels.
2. A motion command older than the deadman (age > ``deadman_ns``) is refused.
3. A motion command whose ``seq`` is not above every stop and motion already
   seen from its sender is refused (issued before that stop, or overtaken) --
   unless its ``stamp`` is later than every one seen from that sender: then
   the sender has started numbering again (a program restarted under the same
   ``sender``), and its numbers count from there.
4. A motion command issued before the latest stop of any *other* sender (or of
   anyone, if it carries no ``seq``) is refused.

Everything here takes times as arguments (CLOCK_MONOTONIC ns for arrivals);
nothing reads a clock, so tests drive it exactly. Memory is bounded: at most
`MAX_SENDERS` senders and clocks are remembered (least recently heard go first).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

MAX_SENDERS = 256
"""Senders (and clocks) remembered; beyond that the least recently heard is forgotten."""
DRIFT = 0.001
"""A clock offset may rise by at most this much per second of arrivals (1 ms/s: drift and
slow changes in delivery time are followed; a stall of 2 s moves it by 2 ms)."""


@dataclass(frozen=True, slots=True)
class Origin:
    """What hwbridge knows about where a command came from and when it was issued."""

    arrival_ns: int
    """hwbridge's CLOCK_MONOTONIC when the command came off the bus."""
    sender: str = ""
    """The sender's own id (`Command.sender`), "" = not given."""
    seq: int = 0
    """The sender's number for this command (`Command.seq`), 0 = not given."""
    clock: str = ""
    """Whose clock ``stamp_ns`` is on ("sender:<id>" or "zenoh:<router id>"), "" = none."""
    stamp_ns: int = 0
    """When it was issued, ns on that clock."""

    @classmethod
    def of(cls, arrival_ns: int, sender: str = "", seq: int = 0, stamp_ns: int = 0,
           zenoh_id: str = "", zenoh_ns: int = 0) -> Origin:
        """The best clock a command offers: its own stamp (with a sender), else Zenoh's."""
        if sender and stamp_ns > 0:
            return cls(arrival_ns, sender, seq, f"sender:{sender}", stamp_ns)
        if zenoh_id and zenoh_ns > 0:
            return cls(arrival_ns, sender, seq, f"zenoh:{zenoh_id}", zenoh_ns)
        return cls(arrival_ns, sender, seq)


class SenderClock:
    """Maps one sender's stamps onto hwbridge's clock: ``issued = stamp + offset``.

    ``offset`` is the smallest ``arrival - stamp`` seen (the clocks' difference plus
    the fastest delivery), allowed to rise by `DRIFT` per second so that a clock
    running slow is followed. The mapped time is never after the arrival.
    """

    def __init__(self, stamp_ns: int, arrival_ns: int) -> None:
        self.offset = arrival_ns - stamp_ns
        self.last_arrival = arrival_ns

    def issued(self, stamp_ns: int, arrival_ns: int) -> int:
        """The issue time of a command stamped ``stamp_ns`` that arrived at ``arrival_ns``."""
        seen = arrival_ns - stamp_ns
        if seen < self.offset:
            self.offset = seen
        else:
            rise = int(max(0, arrival_ns - self.last_arrival) * DRIFT)
            self.offset = min(seen, self.offset + rise)
        self.last_arrival = max(self.last_arrival, arrival_ns)
        return stamp_ns + self.offset


@dataclass(slots=True)
class _Sender:
    last_stop_seq: int = 0
    last_motion_seq: int = 0
    last_stamp: int = 0
    """The latest stamp seen from it (on its own clock)."""
    stop_number: int = 0
    """hwbridge's number of this sender's latest stop (`CommandOrder.stop`)."""


class CommandOrder:
    """Decides, command by command, whether a motion may drive (rules in the module docstring)."""

    def __init__(self, deadman_ns: int, max_senders: int = MAX_SENDERS) -> None:
        self.deadman_ns = deadman_ns
        self.max_senders = max_senders
        self._clocks: OrderedDict[str, SenderClock] = OrderedDict()
        self._senders: OrderedDict[str, _Sender] = OrderedDict()
        # The latest stop (issue time, sender) and the latest from a different sender: enough
        # to answer "the latest stop of anyone but X" for any X.
        self._latest: tuple[int, str] | None = None
        self._runner_up: tuple[int, str] | None = None

    # ------------------------------------------------------------------ time

    def issued(self, o: Origin) -> int:
        """When ``o``'s command was issued, on hwbridge's clock (ns, never after its arrival)."""
        if not o.clock:
            return o.arrival_ns
        clock = self._clocks.get(o.clock)
        if clock is None:
            clock = self._clocks[o.clock] = SenderClock(o.stamp_ns, o.arrival_ns)
            _trim(self._clocks, self.max_senders)
        else:
            self._clocks.move_to_end(o.clock)
        return clock.issued(o.stamp_ns, o.arrival_ns)

    # ------------------------------------------------------------------ stops

    def stop(self, o: Origin, number: int) -> tuple[int, int]:
        """Record a stop that hwbridge numbered ``number``; returns (its issue time, its number).

        A stop repeated with the same sender and ``seq`` (``cmd/stop`` followed by the
        ``cmd/halt`` query that waits for it) is the same stop: its first number is returned.
        """
        issued = self.issued(o)
        if o.sender and o.seq:
            s = self._numbered(o)
            if o.seq == s.last_stop_seq:
                return issued, s.stop_number
            if o.seq > s.last_stop_seq:
                s.last_stop_seq, s.stop_number = o.seq, number
        self._remember_stop(issued, o.sender)
        return issued, number

    def _remember_stop(self, issued: int, sender: str) -> None:
        latest, runner_up = self._latest, self._runner_up
        if latest is None or sender == latest[1]:
            self._latest = (max(issued, latest[0]) if latest else issued, sender)
        elif issued > latest[0]:
            self._latest, self._runner_up = (issued, sender), latest
        elif runner_up is None or sender == runner_up[1] or issued > runner_up[0]:
            self._runner_up = (max(issued, runner_up[0]) if runner_up and sender == runner_up[1]
                               else issued, sender)

    def latest_stop(self, excluding: str | None = None) -> int:
        """Issue time of the latest stop seen (of a sender other than ``excluding``), or -1."""
        for entry in (self._latest, self._runner_up):
            if entry is not None and (excluding is None or entry[1] != excluding):
                return entry[0]
        return -1

    # ------------------------------------------------------------------ motions

    def motion(self, o: Origin) -> tuple[int, str]:
        """(issue time, "") if the motion may drive, else (issue time, why not)."""
        issued = self.issued(o)
        age = o.arrival_ns - issued
        if age > self.deadman_ns:
            return issued, f"issued {age * 1e-9:.3f} s before it arrived (older than the deadman)"
        sender = None
        if o.sender and o.seq:
            sender = self._numbered(o)
            if o.seq <= sender.last_stop_seq:
                return issued, (f"issued before a stop from the same sender "
                                f"(seq {o.seq} <= {sender.last_stop_seq})")
            if o.seq <= sender.last_motion_seq:
                return issued, f"overtaken by a newer command (seq {o.seq} <= {sender.last_motion_seq})"
        latest = self.latest_stop(o.sender if sender is not None else None)
        if issued <= latest:
            return issued, f"issued {(latest - issued) * 1e-6:.1f} ms before the latest stop"
        if sender is not None:
            sender.last_motion_seq = o.seq
        return issued, ""

    def _numbered(self, o: Origin) -> _Sender:
        """The record of ``o``'s sender, its numbering started again if ``o`` says so."""
        s = self._sender(o.sender)
        if o.clock == f"sender:{o.sender}":
            if o.seq <= max(s.last_stop_seq, s.last_motion_seq) and o.stamp_ns > s.last_stamp:
                s.last_stop_seq = s.last_motion_seq = 0  # a lower number, issued later: a restart
            s.last_stamp = max(s.last_stamp, o.stamp_ns)
        return s

    def _sender(self, name: str) -> _Sender:
        s = self._senders.get(name)
        if s is None:
            s = self._senders[name] = _Sender()
            _trim(self._senders, self.max_senders)
        else:
            self._senders.move_to_end(name)
        return s

    @property
    def remembered(self) -> int:
        """Senders and clocks held now (bounded by 2 x ``max_senders``)."""
        return len(self._senders) + len(self._clocks)


def _trim(table: OrderedDict, size: int) -> None:
    while len(table) > size:
        table.popitem(last=False)
