"""The `gateware` verbs: the icoBoard's FPGA design (gateware/, docs/gateware.md).

    icefloe gateware build [CONFIG] [--out DIR]   the bitstream for the robot's [board], with its report
    icefloe gateware pins [CONFIG]                the pin map: which FPGA ball and PMOD pin is what
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import config as config_mod
from .common import add_config_argument


def build(args: argparse.Namespace) -> int:
    from ..gateware.build import build as build_bitstream

    cfg = config_mod.load(args.config or "sim-icoboard")
    out = Path(args.out or Path("build") / "gateware" / cfg.name)
    print(f"building the icoBoard gateware for {cfg.source} in {out} ...", flush=True)
    result = build_bitstream(cfg, out)
    print(result.summary())
    return 0


def pins(args: argparse.Namespace) -> int:
    from ..gateware.platform import pin_map_markdown
    from ..wire.icoboard import Peripherals

    cfg = config_mod.load(args.config or "sim-icoboard")
    print(pin_map_markdown(Peripherals.for_board(cfg.board)))
    return 0


def register(verbs: argparse._SubParsersAction) -> None:
    help_ = "the icoBoard's FPGA design: build the bitstream, show the pin map"
    p = verbs.add_parser("gateware", help=help_, description=help_)
    sub = p.add_subparsers(dest="gateware_verb", required=True, metavar="ACTION", help="build or pins")
    b = sub.add_parser("build", help="build the bitstream for a robot's [board] (default: sim-icoboard); "
                                     "fails unless it meets 100 MHz")
    add_config_argument(b, positional=True)
    b.add_argument("--out", metavar="DIR", help="build folder (default: build/gateware/<robot name>)")
    b.set_defaults(run=build)
    q = sub.add_parser("pins", help="print the pin map for a robot's [board] (default: sim-icoboard)")
    add_config_argument(q, positional=True)
    q.set_defaults(run=pins)
