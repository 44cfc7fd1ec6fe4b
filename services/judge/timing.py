"""The judge's clock: which time a truth sample happened at.

Laps are timed in the simulator's own time (`Truth.sim_time`, its 1 kHz clock), not by the wall
clock: on a busy machine the simulator drops steps (docs/sim.md), the robot then moves less in a
wall second, and a lap timed by wall stamps would be longer than the robot's drive. A truth without
``sim_time`` (an older simulator, a recording of one) is timed by its stamp.
"""

from __future__ import annotations

from icefloe.schemas import messages as m


class TruthTime:
    """Seconds for each truth sample, always forward; and the stamp (ns since the epoch) of a time.

    * ``sim_time`` where the samples carry it. Once one has, a sample without it is refused
      (`seconds` returns None): otherwise a single one, stamped in wall seconds since 1970, would
      jump the judge's clock by decades.
    * Where the simulator started again (its ``sim_time`` went back while the stamps went on), or
      the first sample with ``sim_time`` follows stamp-timed ones, the judge's clock carries on from
      where it was (it does not jump back and refuse the rest).
    """

    def __init__(self) -> None:
        self.base = 0.0
        """Added to the source's seconds, so that the judge's clock carries on across a restart."""
        self.simulated = False
        """Timing by ``sim_time`` (once a sample carried it)."""
        self.last_source = 0.0
        self.last = 0.0
        """The judge's seconds of the newest sample taken."""
        self.offset_ns = 0
        """Stamp minus the judge's time of the newest sample, ns: turns a judge time into a stamp."""

    def seconds(self, truth: m.Truth) -> float | None:
        """The judge's time of ``truth``, s; None if it cannot be timed (no ``sim_time`` where the
        samples have carried one)."""
        if truth.sim_time > 0:
            source = truth.sim_time
            if not self.simulated or source < self.last_source:  # switched to, or started again
                self.base = self.last - source
                self.simulated = True
        elif self.simulated:
            return None
        else:
            source = truth.stamp / 1e9
        self.last_source = source
        t = source + self.base
        self.last = max(self.last, t)
        self.offset_ns = truth.stamp - round(t * 1e9)
        return t

    def stamp(self, t: float) -> int:
        """A judge time as ns since the epoch (by the newest sample's stamp)."""
        return round(t * 1e9) + self.offset_ns
