"""oled rendering: font, frame packing, the user terminal, and golden images of every screen.

Golden images live in ``tests/golden/oled/<name>.pbm`` (binary PBM, lit pixels
white). After an intended change of a screen, regenerate them with

    ICEFLOE_REGEN_GOLDEN=1 .venv/bin/pytest tests/test_oled_render.py

look at the new files, and commit them; a regenerating run skips the comparisons.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import msgspec
import numpy as np
import pytest

from icefloe.schemas import messages as m
from icefloe.services.oled import font
from icefloe.services.oled.frame import COLS, HEIGHT, ROWS, WIDTH, Frame
from icefloe.services.oled.screens import ERRORS, SCREENS, USER, Status, render, view
from icefloe.services.oled.terminal import BOX, Terminal

GOLDEN = Path(__file__).parent / "golden" / "oled"
REGEN = os.environ.get("ICEFLOE_REGEN_GOLDEN") == "1"


def fixed_status() -> Status:
    """The same inputs every time (nothing from this machine: no real addresses or host name)."""
    terminal = Terminal()
    terminal.write("USER TEXT\nhello, robot!\n" + "wraps at twenty-one chars")
    return Status(
        addresses=[("eth0", "192.168.1.20"), ("wlan0", "10.42.0.1")],
        hostname="penguin1",
        terminal=terminal,
        battery=m.Battery(stamp=1, voltage=7.62, current=0.412, state="ok"),
        wheels=m.Wheels(stamp=1, ticks_left=12345, ticks_right=-678, speed_left=0.125,
                        speed_right=-0.05, target_left=0.15, target_right=-0.05),
        tick_zero=(345, 0),
        loop=m.LoopStats(stamp=1, rate=999.8, period_mean=0.001, period_max=0.0013,
                         latency_p50=12e-6, latency_p99=45e-6, latency_p999=80e-6,
                         latency_max=123e-6, overruns=3, cycles=123456, board="penguinpi"),
        alive=["hwbridge", "odometry", "oled", "power", "router", "sim"],
        error=m.Log(stamp=1, level="error", service="hwbridge",
                    text="/dev/serial0: no reply from the board for 0.5 s"),
        errors=2,
        pose=m.Pose(stamp=1, x=1.2345, y=-0.5, theta=math.radians(45)),
    )


CASES: dict[str, tuple[int, Status]] = {
    **{screen.name: (i, fixed_status()) for i, screen in enumerate(SCREENS)},
    "battery-low": (2, Status(battery=m.Battery(stamp=1, voltage=6.83, current=0.3, state="low"))),
    "battery-none": (2, Status()),
    "errors-none": (7, Status()),
    "network-none": (0, Status(hostname="sim")),
    # The lab's TA holds the robot: every screen gives way to the hold's (the pose screen here).
    "held": (8, Status(hold=m.Hold(stamp=1, held=True, since=1, reason="off the table, see me"))),
    "held-owner-may-release": (3, Status(hold=m.Hold(stamp=1, held=True, since=1, owner_may_release=True))),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_screen_matches_golden_image(name: str) -> None:
    index, status = CASES[name]
    frame = render(index, status)
    path = GOLDEN / f"{name}.pbm"
    if REGEN:
        path.parent.mkdir(parents=True, exist_ok=True)
        frame.save_pbm(path)
        pytest.skip(f"regenerated {path}")
    assert path.exists(), f"{path} missing: run with ICEFLOE_REGEN_GOLDEN=1 to create it"
    expected = Frame.from_pbm(path.read_bytes())
    assert frame == expected, f"{name} differs from {path}; got:\n{frame.ascii()}"


@pytest.mark.parametrize("state", ["low", "critical"])
def test_low_battery_inverts_every_screen(state: str) -> None:
    status = fixed_status()
    normal = [render(i, status) for i in range(len(SCREENS))]
    status.battery = m.Battery(stamp=1, voltage=7.62, current=0.412, state=state)  # type: ignore[arg-type]
    for i, screen in enumerate(SCREENS):
        if screen.name != "battery":  # the battery screen also spells the state out
            assert np.array_equal(render(i, status).pixels, 1 - normal[i].pixels), screen.name


def test_a_hold_replaces_every_screen_until_it_is_released() -> None:
    status = fixed_status()
    normal = [render(i, status) for i in range(len(SCREENS))]
    status.hold = m.Hold(stamp=5, held=True, since=5, reason="see me")
    shown = {render(i, status).pack() for i in range(len(SCREENS))}
    assert len(shown) == 1 and shown != {normal[0].pack()}
    assert view(0, status) == view(6, status)  # one screen, whichever was chosen
    status.hold = m.Hold(stamp=6, held=True, since=5, reason="see me")  # hwbridge's once-a-second repeat
    assert view(0, status) == view(3, status)
    status.hold = m.Hold(stamp=7, held=False)  # released: the screens come back
    assert [render(i, status) for i in range(len(SCREENS))] == normal


def test_every_screen_renders_with_no_data_at_all() -> None:
    for index in range(len(SCREENS)):
        assert render(index, Status()).pixels.shape == (HEIGHT, WIDTH)


def test_screen_geometry() -> None:
    assert (COLS, ROWS) == (21, 4)
    assert (SCREENS[USER].name, SCREENS[ERRORS].name) == ("user", "errors")
    assert {chr(c) for c in range(0x20, 0x7F)} == font.CHARSET


def test_glyphs_are_distinct_and_leave_the_spacing_column_dark() -> None:
    cells = {ch: font.cell(ch) for ch in font.CHARSET}
    seen = {cell.tobytes() for cell in cells.values()}
    assert len(seen) == len(cells)  # no two characters look the same
    assert all(not cell[:, 5].any() for cell in cells.values())
    assert font.UNKNOWN_CELL.tobytes() not in seen


def test_pack_is_row_major_msb_first() -> None:
    frame = Frame()
    frame.pixels[0, 0] = frame.pixels[0, 9] = frame.pixels[1, 0] = frame.pixels[31, 127] = 1
    packed = frame.pack()
    assert len(packed) == 512
    assert packed[0] == 0x80 and packed[1] == 0x40 and packed[16] == 0x80 and packed[511] == 0x01
    assert Frame.unpack(packed) == frame
    assert Frame.from_pbm(frame.to_pbm()) == frame


def test_text_is_cut_at_the_right_edge() -> None:
    frame = Frame()
    frame.text(0, 20, "AB")  # only "A" fits in column 20
    assert np.array_equal(frame.pixels[0:8, 120:126], font.cell("A"))
    assert not frame.pixels[:, 126:].any()


def test_terminal_newline_wrap_scroll_and_clear() -> None:
    t = Terminal()
    t.write("one\ntwo\n" + "x" * 25)
    assert t.lines == ["one", "two", "x" * 21, "xxxx"]
    t.write("\nfive")
    assert t.lines == ["two", "x" * 21, "xxxx", "five"]  # scrolled up
    t.write("\fnew")
    assert t.lines == ["new", "", "", ""]
    t.write("\r\tab")
    assert t.lines[0] == "    ab"


def test_terminal_shows_unprintable_characters_safely() -> None:
    t = Terminal()
    t.write("a\x07b\x1b[2Jc é 😀")
    assert t.lines[0] == f"a{BOX}b{BOX}[2Jc e {BOX}"
    assert t.replaced == 3
    frame = Frame()
    frame.text(0, 1, t.lines[0][1])
    assert np.array_equal(frame.pixels[0:8, 6:12], font.UNKNOWN_CELL)


def changed(status: Status, name: str) -> Status:
    """``status`` with field ``name`` set to something else that a screen would show differently."""
    import dataclasses

    other = {
        "addresses": [("wlan0", "10.0.0.99")],
        "hostname": "other",
        "battery": m.Battery(stamp=5, voltage=6.9, current=0.2, state="low"),
        "wheels": m.Wheels(stamp=5, ticks_left=7, ticks_right=8, speed_left=0.5, speed_right=-0.5),
        "tick_zero": (3, 4),
        "loop": None,
        "alive": ["odometry"],
        "error": None,
        "errors": 99,
        "pose": m.Pose(stamp=5, x=-1.0, y=2.5, theta=1.0),
        "hold": m.Hold(stamp=5, held=True, since=5),
    }
    if name == "terminal":
        terminal = Terminal()
        terminal.write("other text")
        return dataclasses.replace(status, terminal=terminal)
    return dataclasses.replace(status, **{name: other[name]})


@pytest.mark.parametrize("index", range(len(SCREENS)))
def test_a_screen_renders_again_only_when_what_it_shows_changed(index: int) -> None:
    """The service renders only when `view` changed: for every screen and every field, an
    equal view must mean an equal frame, and a sensor repeating its values with a new stamp
    (a robot standing still) must not change the view."""
    import dataclasses

    from icefloe.services.oled.screens import view

    base = fixed_status()
    for name in (f.name for f in dataclasses.fields(Status)):
        other = changed(base, name)
        if view(index, other) == view(index, base):
            assert render(index, other) == render(index, base), (SCREENS[index].name, name)
        else:
            assert name in SCREENS[index].reads or name in ("battery", "hold"), (SCREENS[index].name, name)
    restamped = dataclasses.replace(base, wheels=msgspec.structs.replace(base.wheels, stamp=10**9),
                                    pose=msgspec.structs.replace(base.pose, stamp=10**9),
                                    battery=msgspec.structs.replace(base.battery, stamp=10**9))
    assert view(index, restamped) == view(index, base)
