"""The screens, as pure functions from what the robot knows (`Status`) to a `Frame`.

No bus, no clock, no hardware: the same inputs always give the same pixels,
which is what the golden-image tests check. Row 0 of most screens is an
inverted title bar (like the PenguinPi firmware's); its right end names the
screen's button-2 action, if it has one.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Callable
from dataclasses import dataclass, field

import msgspec

from icefloe.schemas import messages as m

from .frame import COLS, ROWS, Frame
from .terminal import Terminal

BATTERY_EMPTY_V = 6.0
"""Battery gauge range, V (2S LiPo: 6.0 V flat, 8.4 V full)."""
BATTERY_FULL_V = 8.4


@dataclass
class Status:
    """Everything the screens show: the latest message of each kind, and the user text."""

    addresses: list[tuple[str, str]] = field(default_factory=list)
    """(interface, IPv4 address) pairs, e.g. ("wlan0", "10.0.0.5")."""
    hostname: str = ""
    terminal: Terminal = field(default_factory=Terminal)
    battery: m.Battery | None = None
    wheels: m.Wheels | None = None
    tick_zero: tuple[int, int] = (0, 0)
    """Encoder counts at the last "reset" on the encoder screen (left, right)."""
    loop: m.LoopStats | None = None
    alive: list[str] = field(default_factory=list)
    """Service names holding a liveliness token."""
    error: m.Log | None = None
    """The last error logged on the bus (None = none, or cleared)."""
    errors: int = 0
    """Errors seen since start."""
    pose: m.Pose | None = None
    hold: m.Hold | None = None
    """hwbridge's last ``hw/hold``: while the lab's TA holds the robot, every screen says so (`held`)."""

    @property
    def held(self) -> bool:
        return self.hold is not None and self.hold.held

    @property
    def inverted(self) -> bool:
        """The whole display is inverted while the battery is low or critical."""
        return self.battery is not None and self.battery.state != "ok"


def _no_data(frame: Frame, what: str) -> Frame:
    frame.text(2, 0, f"no {what} yet".center(COLS))
    return frame


def network(s: Status) -> Frame:
    f = Frame()
    f.title("Network", s.hostname[:12])
    rows = [f"{name[:5]:<5} {address:>15}" for name, address in s.addresses[: ROWS - 1]]
    for row, line in enumerate(rows or ["no network"], start=1):
        f.text(row, 0, line)
    return f


def user(s: Status) -> Frame:
    f = Frame()
    for row, line in enumerate(s.terminal.lines):
        f.text(row, 0, line)
    return f


def battery(s: Status) -> Frame:
    f = Frame()
    f.title("Battery")
    if s.battery is None:
        return _no_data(f, "reading")
    b = s.battery
    f.text(1, 0, f"{b.voltage:6.2f} V {b.current * 1000:7.0f} mA")
    f.text(2, 0, {"ok": "ok", "low": "LOW: charge soon", "critical": "CRITICAL: shutdown"}[b.state])
    f.bar(3, (b.voltage - BATTERY_EMPTY_V) / (BATTERY_FULL_V - BATTERY_EMPTY_V))
    return f


def encoders(s: Status) -> Frame:
    f = Frame()
    f.title("Encoders", "2:reset")
    if s.wheels is None:
        return _no_data(f, "wheels")
    w = s.wheels
    f.text(1, 0, "    ticks      m/s")
    f.text(2, 0, f"L {w.ticks_left - s.tick_zero[0]:8d} {w.speed_left:7.3f}")
    f.text(3, 0, f"R {w.ticks_right - s.tick_zero[1]:8d} {w.speed_right:7.3f}")
    return f


def motors(s: Status) -> Frame:
    f = Frame()
    f.title("Motors m/s")
    if s.wheels is None:
        return _no_data(f, "wheels")
    w = s.wheels
    f.text(1, 0, "    target   speed")
    f.text(2, 0, f"L {w.target_left:8.3f} {w.speed_left:7.3f}")
    f.text(3, 0, f"R {w.target_right:8.3f} {w.speed_right:7.3f}")
    return f


def timing(s: Status) -> Frame:
    f = Frame()
    f.title("Loop", s.loop.board[:14] if s.loop else "")
    if s.loop is None:
        return _no_data(f, "hw/loop")
    lp = s.loop
    f.text(1, 0, f"{lp.rate:7.1f} Hz ovr {lp.overruns:5d}")
    f.text(2, 0, f"p50 {lp.latency_p50 * 1e6:5.0f} p99 {lp.latency_p99 * 1e6:5.0f}")
    f.text(3, 0, f"max {lp.latency_max * 1e6:5.0f} us")
    return f


def services(s: Status) -> Frame:
    f = Frame()
    f.title("Services", str(len(s.alive)))
    lines = textwrap.wrap(" ".join(s.alive), COLS) or ["none alive"]
    for row, line in enumerate(lines[: ROWS - 1], start=1):
        f.text(row, 0, line)
    return f


def errors(s: Status) -> Frame:
    f = Frame()
    f.title(f"Errors {s.errors}", "2:clear")
    if s.error is None:
        f.text(2, 0, "no errors".center(COLS))
        return f
    text = f"{s.error.service}: {s.error.text}"
    # Break anywhere (not only at spaces): a long path or key must still show its start.
    lines = textwrap.wrap(text, COLS, break_long_words=True, replace_whitespace=True)
    for row, line in enumerate(lines[: ROWS - 1], start=1):
        f.text(row, 0, line)
    return f


def pose(s: Status) -> Frame:
    f = Frame()
    f.title("Pose", "2:zero")
    if s.pose is None:
        return _no_data(f, "odom/pose")
    p = s.pose
    f.text(1, 0, f"x {p.x:8.3f} m")
    f.text(2, 0, f"y {p.y:8.3f} m")
    f.text(3, 0, f"th {math.degrees(p.theta):7.1f} deg")
    return f


def held(s: Status) -> Frame:
    """Shown instead of any screen while the lab's TA holds the robot stopped (``hw/hold``)."""
    f = Frame()
    f.title("HELD BY THE LAB'S TA")
    hold = s.hold
    f.text(1, 0, (hold.reason if hold and hold.reason else "wheels stopped")[:COLS])
    f.text(2, 0, "driving refused until")
    f.text(3, 0, "TA or owner releases" if hold and hold.owner_may_release else "the TA releases it")
    return f


@dataclass(frozen=True)
class Screen:
    name: str
    render: Callable[[Status], Frame]
    action: str = ""
    """What button 2 does on this screen ("" = nothing)."""
    reads: tuple[str, ...] = ()
    """The `Status` fields its `render` reads (see `view`)."""


SCREENS: tuple[Screen, ...] = (
    Screen("network", network, reads=("hostname", "addresses")),
    Screen("user", user, "clear", reads=("terminal",)),
    Screen("battery", battery, reads=("battery",)),
    Screen("encoders", encoders, "reset", reads=("wheels", "tick_zero")),
    Screen("motors", motors, reads=("wheels",)),
    Screen("timing", timing, reads=("loop",)),
    Screen("services", services, reads=("alive",)),
    Screen("errors", errors, "clear", reads=("error", "errors")),
    Screen("pose", pose, "zero", reads=("pose",)),
)
"""The screens in button-0 order. The error screen is 7, as on the PenguinPi firmware."""
USER = 1
ERRORS = 7


def render(index: int, status: Status) -> Frame:
    """The frame of screen ``index`` (of `held` while the robot is held), inverted while the battery is low."""
    frame = held(status) if status.held else SCREENS[index].render(status)
    return frame.inverted() if status.inverted else frame


def _shown(value: object) -> object:
    """What of a `Status` field a screen can show: a message without its stamp (a sensor that
    repeats the same values with new stamps changes nothing on the screen), lines as a tuple."""
    if isinstance(value, Terminal):
        return tuple(value.lines)
    if isinstance(value, list):
        return tuple(value)
    if isinstance(value, msgspec.Struct) and hasattr(value, "stamp"):
        return msgspec.structs.replace(value, stamp=0)
    return value


def view(index: int, status: Status) -> tuple[object, ...]:
    """Everything screen ``index`` shows, comparable: while it is equal, `render` gives the same
    frame, so the service renders only when it changed."""
    if status.held:
        return ("held", status.inverted, _shown(status.hold))
    return (index, status.inverted, *(_shown(getattr(status, name)) for name in SCREENS[index].reads))
