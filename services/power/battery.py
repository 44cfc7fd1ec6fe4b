"""Battery state from raw readings: a first-order filter, thresholds and persistence.

Pure logic, no bus and no clock: feed it readings, it tells you the state and
whether a shutdown is due. The service (``__main__``) does the talking.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

State = Literal["ok", "low", "critical"]

MIN_VOLTS = 0.0
MAX_VOLTS = 30.0
"""Plausible range of a raw reading, V. The robot's pack is 2S LiPo (~6-8.4 V);
anything outside this range is a wiring or firmware fault, not a battery level."""
READ_PERIOD_S = 0.5
"""The service takes the battery readings together this often, s: they come at 10 Hz and every
one counts (persistence), but a battery changes over minutes; waking once per reading cost the
service more than everything else it does at rest (bench/stack_cpu.py)."""
READ_BACKLOG = 64
"""Readings Zenoh keeps for the service's next batch (a flood of ``hw/battery`` loses its oldest)."""


class BadReading(ValueError):
    """A raw reading that cannot be a battery voltage."""


@dataclass
class BatteryMonitor:
    """Filters raw voltages and decides ok / low / critical, and when to shut down.

    The filter is ``v = pole * v + (1 - pole) * raw`` (the first reading sets
    ``v``), the same shape as the PenguinPi firmware's ADC smoothing. A
    shutdown is due only after ``critical_readings`` consecutive filtered values
    below ``critical_v``: one noisy sample never powers a robot off.
    """

    low_v: float = 7.0
    """Below this (V) the state is "low": warn, invert the display."""
    critical_v: float = 6.5
    """Below this (V) the state is "critical"."""
    critical_readings: int = 5
    """Consecutive critical readings before a shutdown is due."""
    pole: float = 0.9
    """Filter pole in [0, 1); 0 = no filtering."""

    voltage: float | None = None
    """Filtered voltage, V (None before the first reading)."""
    current: float = 0.0
    """Filtered current, A."""
    critical_count: int = 0
    """Consecutive critical readings so far."""
    last_reading: float = 0.0
    """Time of the last good reading, s (the caller's clock)."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.pole < 1.0:
            raise ValueError(f"power.pole must be in [0, 1), got {self.pole}")
        if self.critical_readings < 1:
            raise ValueError(f"power.critical_readings must be >= 1, got {self.critical_readings}")
        if self.critical_v >= self.low_v:
            raise ValueError(f"power.critical_v ({self.critical_v} V) must be below low_v ({self.low_v} V)")

    def update(self, voltage: float, current: float = 0.0, t: float = 0.0) -> State:
        """Take one raw reading (V, A) taken at time ``t`` (s) and return the new state.

        Raises `BadReading` (and changes nothing) for a voltage outside 0..30 V.
        """
        if not MIN_VOLTS <= voltage <= MAX_VOLTS:
            raise BadReading(f"voltage {voltage} V is outside {MIN_VOLTS:g}..{MAX_VOLTS:g} V")
        if self.voltage is None:
            self.voltage, self.current = voltage, current
        else:
            self.voltage = self.pole * self.voltage + (1.0 - self.pole) * voltage
            self.current = self.pole * self.current + (1.0 - self.pole) * current
        self.last_reading = t
        state = self.state
        self.critical_count = self.critical_count + 1 if state == "critical" else 0
        return state

    @property
    def state(self) -> State:
        if self.voltage is None or self.voltage >= self.low_v:
            return "ok"
        return "critical" if self.voltage < self.critical_v else "low"

    @property
    def shutdown_due(self) -> bool:
        """True once the voltage has been critical for `critical_readings` readings in a row."""
        return self.critical_count >= self.critical_readings

    def silent_while_low(self, now: float, silent_s: float) -> bool:
        """True when the state is low or critical and no reading came for ``silent_s`` s.

        On a PenguinPi the firmware stops everything (readings included) once its
        own smoothed voltage drops below 6.5 V, and its request line to the Pi may
        never go low (penguinpi-facts §8.5): silence while low means the board
        has given up, and the Pi must shut down too.
        """
        return self.state != "ok" and now - self.last_reading >= silent_s
