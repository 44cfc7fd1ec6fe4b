"""The options of the viz service (without importing Rerun, so `icefloe --help` lists them
on a machine that has no `viz` extra)."""

from __future__ import annotations

import argparse
from dataclasses import dataclass


@dataclass(frozen=True)
class VizOptions:
    """What to show and where (the command-line options of ``icefloe viz``)."""

    robot: str | None = None
    """Follow only this robot; None = every robot that has liveliness tokens."""
    serve: bool = False
    """Serve a web viewer (and a gRPC endpoint for native viewers) instead of starting one."""
    save: str | None = None
    """Record to this .rrd file instead of showing a viewer."""
    duration: float | None = None
    """Stop after this many seconds (None = until SIGINT/SIGTERM)."""
    web_port: int = 9090
    grpc_port: int = 9876
    memory_limit: str = "25%"
    """How much the viewer (or the ``--serve`` server) keeps before dropping the oldest data."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The viz options, shared by ``python -m icefloe.services.viz`` and ``icefloe viz``."""
    parser.add_argument("--robot", help="show only this robot (default: every robot found on the bus)")
    sink = parser.add_mutually_exclusive_group()
    sink.add_argument("--serve", action="store_true",
                      help="serve a web viewer and a gRPC endpoint instead of spawning a native viewer")
    sink.add_argument("--save", metavar="FILE.rrd", help="record to a file instead of showing a viewer")
    parser.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    parser.add_argument("--web-port", type=int, default=VizOptions.web_port, metavar="PORT",
                        help=f"with --serve: the web viewer's port (default {VizOptions.web_port})")
    parser.add_argument("--grpc-port", type=int, default=VizOptions.grpc_port, metavar="PORT",
                        help="where native viewers listen: the one viz opens (or finds already open), or, with "
                             f"--serve, this process (default {VizOptions.grpc_port})")
    parser.add_argument("--memory-limit", default=VizOptions.memory_limit,
                        help="data kept in the viewer/server before the oldest is dropped, e.g. 25%% or 2GiB")


def options_from(args: argparse.Namespace) -> VizOptions:
    return VizOptions(robot=args.robot, serve=args.serve, save=args.save, duration=args.duration,
                      web_port=args.web_port, grpc_port=args.grpc_port, memory_limit=args.memory_limit)
