"""The examples in other languages (docs/other-languages.md), as far as this machine can run them.

* C and C++ (examples/c, examples/cpp): built with CMake as a student would; their message code
  (MessagePack from the robot, JSON to it) runs on what icefloe really publishes. Their Zenoh
  part (battery_screen) is not built: no registry of this machine has zenoh-c or zenoh-cpp.
* Rust (examples/rust): not built here at all: crates.io is not reachable.
* The browser example (examples/browser): opened from disk in Debian's Chromium, it follows the
  robot and drives it through the web API's HTTP bridge (cross-origin, as a student's page is).
"""

from __future__ import annotations

import asyncio
import shutil
import subprocess
from pathlib import Path

import msgspec
import pytest
from browser import chromium
from conftest import ROOT
from webapi_helpers import board, webapi, webapi_robot

from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m

STAMP = 1_800_000_000_000_000_001
"""A stamp a double cannot hold exactly: the examples read it as a 64-bit integer."""


def build(language: str, tmp_path: Path) -> Path:
    """``cmake`` and ``cmake --build`` of examples/<language>; its test_battery program."""
    if shutil.which("cmake") is None:
        pytest.skip("cmake is not installed")
    if not (Path("/usr/include/msgpack.h").exists() and Path("/usr/include/msgpack.hpp").exists()):
        pytest.skip("msgpack-c/-cxx are not installed (tests/run.sh: apt-get install libmsgpack-dev "
                    "libmsgpack-cxx-dev)")
    out = tmp_path / language
    for step in (["cmake", "-S", str(ROOT / "examples" / language), "-B", str(out)],
                 ["cmake", "--build", str(out), "--target", "test_battery"]):
        done = subprocess.run(step, capture_output=True, text=True, timeout=240)
        assert done.returncode == 0, done.stdout + done.stderr
    return out / "test_battery"


@pytest.mark.parametrize("language", ["c", "cpp"])
def test_the_message_code_reads_what_the_robot_publishes(language: str, tmp_path: Path) -> None:
    program = build(language, tmp_path)

    def run(payload: bytes) -> subprocess.CompletedProcess[str]:
        return subprocess.run([str(program)], input=payload.decode("latin-1"), encoding="latin-1",
                              capture_output=True, timeout=30)

    sent = run(codec.encode(m.BatteryReading(stamp=STAMP, voltage=7.4, current=0.3)))
    assert sent.returncode == 0, sent.stderr
    stamp, json = sent.stdout.strip().split(" ", 1)
    assert int(stamp) == STAMP
    assert codec.decode(json.encode(), codec.JSON, m.OledText, "oled/text") == m.OledText(text="battery 7.40 V")
    # A map in another order, a voltage as an integer, a field it does not know: still read.
    other = msgspec.msgpack.encode({"current": 0, "extra": [1], "voltage": 8, "stamp": 5})
    assert run(other).stdout.strip() == '5 {"text": "battery 8.00 V"}'
    for bad in (b"", b"\xc1", msgspec.msgpack.encode([STAMP, 7.4, 0.3]),  # an array: refused
                msgspec.msgpack.encode({"stamp": 1, "voltage": "high", "current": 0})):
        refused = run(bad)
        assert refused.returncode == 1 and "not a BatteryReading" in refused.stderr, bad


@pytest.mark.slow
async def test_the_browser_example_follows_and_drives_the_robot(make_robot, tmp_path: Path) -> None:
    robot = webapi_robot(make_robot)
    async with webapi(robot) as http, board(robot) as b, robot.node("tester") as node, \
            chromium(tmp_path / "profile") as context:
        b.battery = m.BatteryReading(stamp=0, voltage=7.9, current=0.2)
        twists, stops = node.subscribe(keys.TWIST, latest=False), node.subscribe(keys.STOP)
        page = await context.new_page()
        page_url = (ROOT / "examples" / "browser" / "index.html").as_uri()
        await page.goto(f"{page_url}?robot={http.base}")  # file://: every request is cross-origin
        await page.wait_for_function("document.getElementById('battery').textContent === '7.90'",
                                     timeout=30_000)
        button = await page.locator("#forward").bounding_box()
        await page.mouse.move(button["x"] + 10, button["y"] + 10)
        await page.mouse.down()
        twist = await asyncio.wait_for(anext(twists), 10)
        assert (twist.v, twist.w) == (0.15, 0.0)
        await asyncio.wait_for(anext(twists), 5)  # repeated while held
        await page.mouse.up()
        await asyncio.wait_for(anext(stops), 10)
        assert await page.inner_text("#state") == "stopped"
