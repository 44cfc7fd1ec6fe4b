"""``python -m icefloe.services.viz`` (or ``icefloe viz``): a live Rerun view of a robot, from a laptop.

    icefloe viz --connect tcp/penguin1.local:7447            # every robot on that bus, native viewer
    icefloe viz --connect tcp/10.0.0.5:7447 --robot penguin1 --serve
    icefloe viz --robot sim --save run.rrd --duration 60     # record, no viewer
"""

from __future__ import annotations

import argparse
import functools
from collections.abc import Sequence

from icefloe.runtime import run

from .options import add_arguments, options_from


def add_service_arguments(parser: argparse.ArgumentParser) -> None:
    """The options every service takes (handed on to `run`), then the viz options."""
    parser.add_argument("--config", help="robot config: a name (sim, penguin1) or a path to a .toml file")
    parser.add_argument("--connect", action="append", metavar="ENDPOINT",
                        help="Zenoh endpoint of the robot's router, e.g. tcp/10.0.0.5:7447")
    parser.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING or ERROR (default INFO)")
    add_arguments(parser)


def start(args: argparse.Namespace) -> None:
    """Run the viz service with parsed options until it ends or Ctrl-C."""
    from .app import main  # imports Rerun (the `viz` extra)

    common = ["--log-level", args.log_level]
    if args.config:
        common += ["--config", args.config]
    for endpoint in args.connect or []:
        common += ["--connect", endpoint]
    run(functools.partial(main, options=options_from(args)), common, description="icefloe viz")


def cli(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="icefloe viz", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_service_arguments(parser)
    start(parser.parse_args(argv))


if __name__ == "__main__":
    cli()
