"""Query-string parameters of the PenguinPi web API: parsing, checks and units.

Pure functions, no I/O: each returns a checked value or raises `InvalidCommand`
with one message naming the parameter and what was wrong. A handler parses
*every* parameter before it sends anything, so a rejected request never moves
the robot.

Messages start with the old server's text (``invalid speeds``, ``bad time
given``, ...) so they read like the old ones, and then say what was wrong.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping

from icefloe.config import Geometry

_NUMBER = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?\Z")
"""A plain decimal number. Python's float() would also take 'nan', 'inf' and '1_0'."""

_INTEGER = re.compile(r"[+-]?\d+\Z")

MAX_TEXT = 1000
"""Longest text accepted by /hat/screen/print, characters (the screen shows 4 x 20)."""


class InvalidCommand(Exception):
    """A request the API refuses: HTTP 400 with ``{"message": ...}``, nothing sent to the robot."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


def demand_to_mps(geometry: Geometry) -> float:
    """Rim speed (m/s) of one PenguinPi firmware demand unit.

    The firmware's speed loop runs every 20 ms with target = demand / 5 counts,
    so demand D means 10 * D counts/s; one count is pi * d / ticks_per_rev of rim.
    With the PenguinPi's 65 mm wheels and 384 counts per turn: about 5.32 mm/s.
    """
    return 10 * math.pi * geometry.wheel_diameter / geometry.ticks_per_rev


def _number(text: str, what: str) -> float:
    if not _NUMBER.match(text.strip()):
        raise InvalidCommand(f"{what}: {text!r} is not a number")
    value = float(text)
    if not math.isfinite(value):  # e.g. 1e999
        raise InvalidCommand(f"{what}: {text!r} is too large")
    return value


def _required(query: Mapping[str, str], name: str, what: str) -> str:
    text = query.get(name)
    if text is None or not text.strip():
        raise InvalidCommand(f"{what}: missing {name}=")
    return text


def speeds(query: Mapping[str, str], max_demand: int) -> tuple[float, float]:
    """``value=L,R``: wheel demands in firmware units, each within +-max_demand.

    The old server took integers only; we also take decimals (``50.0``), which
    is what pibot_client sends when given floats.
    """
    what = "invalid speeds"
    text = _required(query, "value", what)
    fields = text.split(",")
    if len(fields) != 2:
        raise InvalidCommand(f"{what}: value={text!r}: expected two numbers, left,right")
    left, right = (_number(f, f"{what}: value={text!r}") for f in fields)
    for side, v in (("left", left), ("right", right)):
        if abs(v) > max_demand:
            raise InvalidCommand(f"{what}: {side} speed {v:g} is outside -{max_demand}..{max_demand}")
    return left, right


def timing(query: Mapping[str, str], max_time: float) -> tuple[float | None, float]:
    """``time=T`` (s, optional) and ``accel=A`` (s, ramp length; ``acceleration=`` too).

    Returns (None, 0) without ``time``. The motion ramps up over A, cruises,
    ramps down over A; it needs T > 2 A, as the old server did.
    """
    if "time" not in query:
        if "accel" in query or "acceleration" in query:
            raise InvalidCommand("bad acceleration given: accel= needs time=")
        return None, 0.0
    duration = _number(query["time"], "bad time given: time")
    if duration <= 0:
        raise InvalidCommand(f"bad time given: time={duration:g} must be > 0 s")
    if duration > max_time:
        raise InvalidCommand(f"bad time given: time={duration:g} is longer than {max_time:g} s")
    names = [n for n in ("accel", "acceleration") if n in query]
    if len(names) == 2:
        raise InvalidCommand("bad acceleration given: give accel= or acceleration=, not both")
    accel = _number(query[names[0]], f"bad acceleration given: {names[0]}") if names else 0.0
    if accel < 0:
        raise InvalidCommand(f"bad acceleration given: {names[0]}={accel:g} must be >= 0 s")
    if duration <= 2 * accel:
        raise InvalidCommand(
            f"acceleration time too long: time={duration:g} must be more than 2 x accel={accel:g}")
    return duration, accel


def integer(query: Mapping[str, str], name: str, what: str, low: int, high: int,
            *, any_base: bool = False, decimals: bool = False) -> int:
    """An integer parameter within [low, high].

    ``any_base``: also 0x.. and 0b.. (as the old server's int(text, 0) did);
    ``decimals``: also '100.0' when it is a whole number (pibot_client sends that).
    """
    text = _required(query, name, what).strip()
    value: float | int
    try:
        if any_base:
            value = int(text, 0)
        elif _INTEGER.match(text):
            value = int(text)
        elif decimals:
            value = _number(text, f"{what}: {name}")
            if value != int(value):
                raise InvalidCommand(f"{what}: {name}={text!r} is not a whole number")
            value = int(value)
        else:
            raise ValueError(text)
    except ValueError:
        raise InvalidCommand(f"{what}: {name}={text!r} is not an integer") from None
    if not low <= value <= high:
        raise InvalidCommand(f"{what}: {name}={value} is outside {low}..{high}")
    return int(value)


def text(query: Mapping[str, str]) -> str:
    """``value=`` of /hat/screen/print: any text up to MAX_TEXT characters."""
    value = query.get("value")
    if value is None:
        raise InvalidCommand("Bad text: missing value=")
    if len(value) > MAX_TEXT:
        raise InvalidCommand(f"Bad text: {len(value)} characters, at most {MAX_TEXT}")
    return value


def to_int16(count: int) -> int:
    """An unwrapped encoder count as the firmware's signed 16-bit counter shows it."""
    return (count + 0x8000) % 0x10000 - 0x8000
