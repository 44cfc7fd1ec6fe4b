"""``python -m icefloe.services.viz`` (or ``icefloe viz``): a live Rerun view of a robot, from a laptop.

    icefloe viz --connect tcp/penguin1.local:7447            # every robot on that bus, native viewer
    icefloe viz --connect tcp/10.0.0.5:7447 --robot penguin1 --serve
    icefloe viz --robot sim --save run.rrd --duration 60     # record, no viewer
"""

from __future__ import annotations

import argparse
import functools
import sys
from collections.abc import Sequence

from icefloe.errors import IcefloeError
from icefloe.runtime import run

from .options import add_arguments, options_from
from .viewer import display_problem, how_to_look


def add_service_arguments(parser: argparse.ArgumentParser) -> None:
    """The options every service takes (handed on to `run`), then the viz options."""
    parser.add_argument("--config", help="robot config: a name (sim, penguin1) or a path to a .toml file")
    parser.add_argument("--connect", action="append", metavar="ENDPOINT",
                        help="Zenoh endpoint of the robot's router, e.g. tcp/10.0.0.5:7447")
    parser.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING or ERROR (default INFO)")
    add_arguments(parser)


def check_viewer(args: argparse.Namespace, how: str = "") -> None:
    """An IcefloeError in one line (exit 2: not the config's fault) if no window can open here
    (checked before seconds of importing Rerun)."""
    if not (args.save or args.serve) and (problem := display_problem()):
        raise IcefloeError(f"cannot open the Rerun viewer: {problem}; {how or how_to_look()}")


def start(args: argparse.Namespace) -> None:
    """Run the viz service with parsed options until it ends or Ctrl-C."""
    check_viewer(args)
    try:
        from .app import main  # imports Rerun (the `viz` extra)
    except ImportError as exc:
        raise IcefloeError(f"viz needs the Rerun SDK: pip install 'icefloe[viz]' ({exc})") from None

    common = ["--log-level", args.log_level]
    if args.config:
        common += ["--config", args.config]
    for endpoint in args.connect or []:
        common += ["--connect", endpoint]
    run(functools.partial(main, options=options_from(args)), common, description="icefloe viz")


def show_recording(args: argparse.Namespace) -> int:
    """``icefloe viz FILE.mcap``: the same view of a recording (exit status)."""
    check_viewer(args, "add --save FILE.rrd and open that on a machine with a screen (rerun FILE.rrd), "
                       "or --serve and open http://localhost:9090 in a browser")
    try:
        from .playback import show_files  # imports Rerun (the `viz` extra)
    except ImportError as exc:
        raise IcefloeError(f"viz needs the Rerun SDK: pip install 'icefloe[viz]' ({exc})") from None
    from icefloe.runtime import load_config

    return show_files(args.files, load_config(args), options_from(args))


def cli(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="icefloe viz", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_service_arguments(parser)
    try:
        start(parser.parse_args(argv))
    except IcefloeError as exc:  # (a bad config, no display, no viewer: one line)
        print(f"icefloe viz: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
