"""What the verb modules share: the robot/bus options, key names, printing samples."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
from collections.abc import Callable
from typing import Any

import msgspec

from ..config import RobotConfig
from ..runtime import Node, RawSample, load_config
from ..schemas import codec, keys


def add_config_argument(parser: argparse.ArgumentParser, *, positional: bool = False) -> None:
    """The robot a verb is about: ``CONFIG`` (positional) or ``--config``."""
    help_ = "robot config: a name (sim, penguin1) or a path to a .toml file (default: sim)"
    if positional:
        parser.add_argument("config", nargs="?", metavar="CONFIG", help=help_)
    else:
        parser.add_argument("--config", help=help_)


def add_bus_arguments(parser: argparse.ArgumentParser,
                      robot_help: str = "robot name on the bus (default: the config's)") -> argparse.ArgumentParser:
    """The options of every verb that opens a session: which robot, where, as whom."""
    add_config_argument(parser)
    parser.add_argument("--connect", action="append", metavar="ENDPOINT",
                        help="Zenoh endpoint of the robot's router, e.g. tcp/10.0.0.5:7447 (repeatable)")
    parser.add_argument("--robot", help=robot_help)
    parser.add_argument("--credentials", metavar="FILE",
                        help="a robot's credentials file (robot, user, password, address): drive it as its owner")
    return parser


def bus_config(args: argparse.Namespace) -> RobotConfig:
    """The config of a bus verb, with --connect and --credentials applied."""
    cfg = load_config(args)
    if args.credentials:
        from ..credentials import read

        creds = read(args.credentials)
        zenoh = msgspec.structs.replace(cfg.zenoh, user=creds.user, password=creds.password,
                                        connect=args.connect or creds.connect or cfg.zenoh.connect)
        cfg = msgspec.structs.replace(cfg, name=creds.robot, zenoh=zenoh)
        args.robot = args.robot or creds.robot
    return cfg


def cli_node(config: RobotConfig) -> Node:
    """The session of a command-line tool: no liveliness token, fails fast without a router."""
    return Node("cli", config, announce=False, retry=False)


def resolve_key(key: str, robot: str) -> str:
    """A full key from a key-table name (``odom/pose``) on ``robot``, or ``key`` if it is full."""
    return key if key.startswith(keys.PREFIX + "/") else keys.key(robot, key)


def printable(value: Any) -> Any:
    """Plain JSON-able data, with byte strings shown as their length (images are large)."""
    if isinstance(value, bytes | bytearray):
        return f"<{len(value)} bytes>"
    if isinstance(value, dict):
        return {k: printable(v) for k, v in value.items()}
    if isinstance(value, list):
        return [printable(v) for v in value]
    return value


def describe(raw: RawSample) -> Any:
    """Decode a sample by the key table (or generically) into printable data."""
    topic = keys.topic_of(raw.key)
    if topic is not None and topic.kind != "query":
        msg = codec.decode(raw.payload, raw.encoding, topic.type, raw.key)
        return printable(msgspec.to_builtins(msg, builtin_types=(bytes,)))
    return printable(codec.to_builtins(raw.payload, raw.encoding))


class Done(Exception):
    """Raised by a sample handler to end `drain` early."""


async def drain(sub: Any, duration: float | None, handle: Callable[[RawSample], None]) -> None:
    """Feed samples to ``handle`` for ``duration`` seconds (None = until Ctrl-C or `Done`)."""
    async def loop() -> None:
        async for raw in sub:
            handle(raw)

    with contextlib.suppress(Done):
        if duration:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(loop(), duration)
        else:
            await loop()
