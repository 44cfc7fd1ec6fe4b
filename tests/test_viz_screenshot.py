"""tools/viz_screenshot.py makes the README's picture from the real simulated stack, driven, with
the log panel filled: its recording holds all of that, and the PNG is a full-size picture of it."""

from __future__ import annotations

import math
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import pytest
from conftest import ROOT

from icefloe.services.viz.readback import read_rrd

LAVAPIPE = list(Path("/usr/share/vulkan/icd.d").glob("lvp_icd*.json"))


def png_size_and_colours(path: Path) -> tuple[tuple[int, int], int]:
    """(width, height) and how many different bytes the first rows of pixels hold (0-1: blank)."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    chunks, i = b"", 8
    while i < len(data):
        length, kind = struct.unpack(">I4s", data[i:i + 8])
        if kind == b"IDAT":
            chunks += data[i + 8:i + 8 + length]
        i += 12 + length
    pixels = zlib.decompress(chunks)
    return (width, height), len(set(pixels[: len(pixels) // 2]))


@pytest.mark.slow
@pytest.mark.timeout(400)
def test_the_screenshot_is_of_the_driven_stack_with_its_log(tmp_path: Path) -> None:
    if not LAVAPIPE:
        pytest.skip("no software Vulkan for the headless viewer: apt-get install mesa-vulkan-drivers "
                    "(tests/run.sh does it as root)")
    shot, rrd = tmp_path / "shot.png", tmp_path / "run.rrd"
    done = subprocess.run([sys.executable, "tools/viz_screenshot.py", "--out", str(shot), "--keep", str(rrd)],
                          cwd=ROOT, capture_output=True, text=True, timeout=380)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    data = read_rrd(rrd)
    root = "/robots/sim"
    logs = [text[0] for text in data[f"{root}/log"]["TextLog:text"] if text]
    assert any("[hwbridge]" in t and "dropped" in t for t in logs), logs  # the bad command
    assert sum("[odometry]" in t or "[localizer]" in t or "[camera]" in t for t in logs) >= 3, logs  # start-up
    truth = [row[0] for row in data[f"{root}/map/truth"]["Arrows2D:origins"] if row]
    assert math.dist(truth[0], truth[-1]) > 0.3  # it was driven
    assert data[f"{root}/camera/image"]["log_time"] and data[f"{root}/oled"]["log_time"]
    size, colours = png_size_and_colours(shot)
    assert size == (1920, 1080) and colours > 20
