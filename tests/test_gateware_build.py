"""`icefloe gateware build`: the bitstream for the icoBoard, built here with the YoWASP toolchain."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]  # a fresh machine first compiles the YoWASP tools


def test_the_bitstream_builds_and_meets_100_mhz(tmp_path: Path) -> None:
    out = tmp_path / "build"
    done = subprocess.run([sys.executable, "-m", "icefloe.cli", "gateware", "build", "sim-icoboard",
                           "--out", str(out)], capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    report = done.stdout.strip().splitlines()[-1]
    print(f"\n{report}")
    assert (out / "icoboard.bin").stat().st_size > 100_000  # an HX8K image is ~132 kB
    fmax = float(re.search(r"Fmax ([\d.]+) MHz \(constraint 100 MHz: met\)", report).group(1))
    assert fmax >= 100
    pcf = (out / "icoboard.pcf").read_text()
    assert "R9" in pcf and "R11" in pcf  # the oscillator and the Pi's SPI clock


def test_a_board_the_gateware_cannot_build_is_refused_in_one_line(tmp_path: Path) -> None:
    config = tmp_path / "wide.toml"
    config.write_text(f'extends = "{ROOT / "deploy" / "robots" / "sim-icoboard.toml"}"\n[board]\nsensors = 9\n')
    done = subprocess.run([sys.executable, "-m", "icefloe.cli", "gateware", "build", str(config),
                           "--out", str(tmp_path / "b")], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 2
    assert done.stderr.strip() == "icefloe: the gateware builds 1..8 sensors, the peripheral list has 9"
