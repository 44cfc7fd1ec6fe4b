"""``python -m icefloe.services.viz``: a live Rerun view of a robot, from a laptop.

    python -m icefloe.services.viz --connect tcp/penguin1.local:7447            # every robot, native viewer
    python -m icefloe.services.viz --connect tcp/10.0.0.5:7447 --robot penguin1 --serve
    python -m icefloe.services.viz --robot sim --save run.rrd --duration 60    # record, no viewer
"""

from __future__ import annotations

import argparse
import functools
from collections.abc import Sequence

from icefloe.runtime import run

from .app import VizOptions, main


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The viz options (the lead's ``icefloe viz`` subcommand adds the same ones)."""
    parser.add_argument("--robot", help="show only this robot (default: every robot found on the bus)")
    sink = parser.add_mutually_exclusive_group()
    sink.add_argument("--serve", action="store_true",
                      help="serve a web viewer and a gRPC endpoint instead of spawning a native viewer")
    sink.add_argument("--save", metavar="FILE.rrd", help="record to a file instead of showing a viewer")
    parser.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    parser.add_argument("--web-port", type=int, default=VizOptions.web_port)
    parser.add_argument("--grpc-port", type=int, default=VizOptions.grpc_port)
    parser.add_argument("--memory-limit", default=VizOptions.memory_limit,
                        help="data kept in the viewer/server before the oldest is dropped, e.g. 25%% or 2GiB")


def options_from(args: argparse.Namespace) -> VizOptions:
    return VizOptions(robot=args.robot, serve=args.serve, save=args.save, duration=args.duration,
                      web_port=args.web_port, grpc_port=args.grpc_port, memory_limit=args.memory_limit)


def cli(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m icefloe.services.viz", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    # The options every service takes, handed on to `run` below.
    parser.add_argument("--config", help="robot config: a TOML file or a name in deploy/robots (default: sim)")
    parser.add_argument("--connect", action="append", help="Zenoh endpoint of the robot, e.g. tcp/10.0.0.5:7447")
    parser.add_argument("--log-level", default="INFO")
    add_arguments(parser)
    args = parser.parse_args(argv)
    common = ["--log-level", args.log_level]
    if args.config:
        common += ["--config", args.config]
    for endpoint in args.connect or []:
        common += ["--connect", endpoint]
    run(functools.partial(main, options=options_from(args)), common, description="icefloe viz")


if __name__ == "__main__":
    cli()
