"""Parts of the PenguinPi firmware model: defect switches, motor and ADC state, AVR arithmetic.

Used by ``penguinpi_firmware.py``; the numbers are from penguinpi-facts.md §3.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, fields

HW_MV_PER_COUNT = 3.3 / 1024 / 0.20 * 1000
"""What one ADC count really is on the voltage divider, mV (report: 16.11)."""
HW_MA_PER_COUNT = 3.3 / 1024 / 0.05 / 20 * 1000
"""What one ADC count really is on the 0.05 ohm shunt x20 amplifier, mA (report: 3.223)."""

@dataclass(frozen=True)
class Defects:
    """Which real-firmware defects (facts §8) the model reproduces. All True = the real board."""

    enc_zero_keeps_prev: bool = True
    """MOTOR_SET_ENC_ZERO leaves the previous sample, so the next velocity sample spikes."""
    mode_ops_want_4_bytes: bool = True
    """MOTOR_SET_ENC_MODE / _CONTROL_MODE require 4 payload bytes (fixed: 1 byte) (§8.8)."""
    screen_error_names_ip_eth: bool = True
    """HAT_SET_SCREEN's length error names HAT_SET_IP_ETH (§8.8)."""
    adc_value_float_bits: bool = True
    """ADC_GET_VALUE replies 2 bytes of the float's bit pattern (fixed: the 4-byte float) (§8.9)."""
    open_loop_stale_direction: bool = True
    """Open-loop mode takes the direction from the stale PI output, not the demand (§8.3)."""
    dip_unshifted_at_boot: bool = True
    """HAT_GET_DIP returns DIP x 16 until the first HAT interrupt (§8.11)."""
    pb5_not_output: bool = True
    """PB5 is never made an output, so the low-battery request never pulls GPIO10 low (§8.5)."""

    @classmethod
    def fixed(cls) -> Defects:
        """Every defect corrected."""
        return cls(**{f.name: False for f in fields(cls)})


def int16(value: int) -> int:
    """Wrap to a signed 16-bit integer, as the AVR's int16_t arithmetic does."""
    return (value + 0x8000) % 0x10000 - 0x8000


def f32(value: float) -> float:
    """Round to IEEE-754 single precision (the AVR's float)."""
    return struct.unpack(">f", struct.pack(">f", value))[0]


def clamp(value: int, limit: int) -> int:
    return max(-limit, min(limit, value))


@dataclass
class Motor:
    """One motor's state, as the firmware's ``Motor`` struct (all int16)."""

    demand: int = 0
    kvp: int = 0
    kvi: int = 1
    enc_mode: int = 1
    control_mode: int = 0
    position: int = 0
    position_prev: int = 0
    integral: int = 0
    command: int = 0
    error: int = 0
    measured: int = 0
    """Counts per 20 ms at the last control step."""

    def control(self) -> None:
        """One 20 ms step of the integer PI velocity controller (facts §3.3)."""
        target = int(self.demand / 5)                  # C division truncates toward zero
        self.measured = int16(self.position - self.position_prev)
        self.position_prev = self.position
        self.error = int16(target - self.measured)
        self.integral = clamp(int16(self.integral + self.error), 100) if self.kvi > 0 else 0
        self.command = clamp(int16(self.kvp * self.error + self.kvi * self.integral), 100)


@dataclass
class Adc:
    """One ADC channel: firmware scale (units/count), filter pole, last value and smoothed value."""

    scale: float
    hw_per_count: float
    pole: float = f32(0.95)
    value: float = 0.0
    smooth: float = 0.0
    samples: int = 0

    def sample(self, physical: float) -> None:
        """Convert ``physical`` (mV or mA) with the 10-bit ADC, then scale and filter as the firmware."""
        raw = max(0, min(1023, round(physical / self.hw_per_count)))
        self.value = f32(raw * self.scale)
        if self.samples == 0:
            self.smooth = self.value
        else:
            self.smooth = f32(self.pole * self.smooth + (1.0 - self.pole) * self.value)
        self.samples += 1
