"""Verbs that look at and talk to a robot's bus: status, topics, echo, hz, pub, query."""

from __future__ import annotations

import argparse
import asyncio
import json
import time
from collections import defaultdict
from collections.abc import Awaitable, Callable

import msgspec

from ..config import RobotConfig
from ..errors import BadPayload, IcefloeError
from ..runtime import RawSample, run_async
from ..schemas import codec, keys
from .common import Done, add_bus_arguments, bus_config, cli_node, describe, drain, printable, resolve_key

BusVerb = Callable[[argparse.Namespace, RobotConfig], Awaitable[int]]


def on_bus(verb: BusVerb) -> Callable[[argparse.Namespace], int]:
    """Run an async bus verb with the config its options name."""
    def run(args: argparse.Namespace) -> int:
        return run_async(verb(args, bus_config(args)))

    return run


def robot_of(args: argparse.Namespace, config: RobotConfig) -> str:
    return args.robot or config.name


async def status(args: argparse.Namespace, config: RobotConfig) -> int:
    async with cli_node(config) as node:
        tokens = await node.alive(args.robot or "*")
    by_robot: dict[str, list[str]] = defaultdict(list)
    for token in tokens:
        _, robot, _, service = token.split("/", 3)
        if service not in by_robot[robot]:
            by_robot[robot].append(service)
    if not by_robot:
        print("no robot is alive on this bus")
        return 1
    for robot, services in sorted(by_robot.items()):
        print(f"{robot}: {' '.join(sorted(services))}")
    return 0


async def topics(args: argparse.Namespace, config: RobotConfig) -> int:
    counts: dict[str, int] = defaultdict(int)
    async with cli_node(config) as node:
        sub = node.subscribe_raw(f"{keys.PREFIX}/{args.robot or '*'}/**", maxsize=100_000)
        await drain(sub, args.duration, lambda raw: counts.__setitem__(raw.key, counts[raw.key] + 1))
    for key in sorted(counts):
        topic = keys.topic_of(key)
        kind = topic.type.__name__ if topic else "?"
        print(f"{key:<44} {counts[key] / args.duration:8.1f} Hz  {kind}")
    return 0


async def echo(args: argparse.Namespace, config: RobotConfig) -> int:
    key = resolve_key(args.key, robot_of(args, config))
    wildcard = "*" in key
    seen = 0
    async with cli_node(config) as node:
        sub = node.subscribe_raw(key)

        def show(raw: RawSample) -> None:
            nonlocal seen
            try:
                text = json.dumps(describe(raw))
            except (BadPayload, msgspec.DecodeError, IcefloeError) as exc:
                text = json.dumps({"error": str(exc)})
            print(f"{raw.key} {text}" if wildcard else text, flush=True)
            seen += 1
            if args.count and seen >= args.count:
                raise Done

        await drain(sub, args.duration, show)
    return 0


async def hz(args: argparse.Namespace, config: RobotConfig) -> int:
    key = resolve_key(args.key, robot_of(args, config))
    async with cli_node(config) as node:
        sub = node.subscribe_raw(key, maxsize=100_000)
        end = time.monotonic() + (args.duration or float("inf"))
        while time.monotonic() < end:
            stamps: list[float] = []
            await drain(sub, 1.0, lambda raw, into=stamps: into.append(raw.received))
            rate = (len(stamps) - 1) / (stamps[-1] - stamps[0]) if len(stamps) > 2 else 0.0
            print(f"{key}: {rate:.1f} Hz ({len(stamps)} messages in the last second)", flush=True)
    return 0


async def pub(args: argparse.Namespace, config: RobotConfig) -> int:
    key = resolve_key(args.key, robot_of(args, config))
    topic = keys.topic_of(key)
    if topic is None or topic.kind == "query":
        known = ", ".join(t.name for t in keys.TABLE.values() if t.kind != "query")
        raise IcefloeError(f"{key}: not a topic one can publish to (known: {known})")
    message = codec.decode(args.json.encode(), codec.JSON, topic.type, key)
    async with cli_node(config) as node:
        await asyncio.sleep(0.2)  # let the router learn our publisher before the first put
        publisher = node.publisher(topic) if key == node.key(topic) else None
        payload = codec.encode(message)
        period = 1.0 / args.rate if args.rate else 0.0
        sent = 0
        while True:
            if publisher is not None:
                publisher.put(message)
            else:
                node.session.put(key, payload, encoding=codec.MSGPACK)
            sent += 1
            if not period or (args.count and sent >= args.count):
                break
            await asyncio.sleep(period)
        await asyncio.sleep(0.1)
    return 0


async def query(args: argparse.Namespace, config: RobotConfig) -> int:
    key = resolve_key(args.key, robot_of(args, config))
    topic = keys.topic_of(key)
    if topic is None or topic.kind != "query":
        known = ", ".join(t.name for t in keys.TABLE.values() if t.kind == "query")
        raise IcefloeError(f"{key}: not a queryable (known: {known})")
    request = codec.decode((args.json or "{}").encode(), codec.JSON, topic.type, key)
    robot, _ = keys.split(key)
    async with cli_node(config) as node:
        reply = await node.query(topic, request, timeout=args.timeout, robot=robot)
    print(json.dumps(printable(msgspec.to_builtins(reply, builtin_types=(bytes,)))))
    return 0


def register(verbs: argparse._SubParsersAction) -> None:
    def verb(name: str, run: BusVerb, help_: str) -> argparse.ArgumentParser:
        p = verbs.add_parser(name, help=help_, description=help_)
        add_bus_arguments(p)
        p.set_defaults(run=on_bus(run))
        return p

    verb("status", status, "which services are alive, per robot")
    verb("topics", topics, "keys seen on the bus, with rates").add_argument(
        "--duration", type=float, default=3.0, metavar="S", help="listen this long (default 3 s)")
    p = verb("echo", echo, "print a key's messages as JSON lines")
    p.add_argument("key", help="a key-table name (odom/pose) or a full key; wildcards allowed")
    p.add_argument("--count", type=int, default=0, metavar="N", help="stop after N messages")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    p = verb("hz", hz, "the message rate of a key, once a second")
    p.add_argument("key", help="a key-table name (hw/wheels) or a full key")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    p = verb("pub", pub, "publish a message given as JSON (checked against the key's message first)")
    p.add_argument("key", help="an input key (cmd/twist) or a full key")
    p.add_argument("json", help='the message as JSON, e.g. \'{"v": 0.1, "w": 0.5}\'')
    p.add_argument("--rate", type=float, default=0.0, metavar="HZ", help="repeat at this rate")
    p.add_argument("--count", type=int, default=0, metavar="N", help="with --rate: stop after N")
    p = verb("query", query, "ask a queryable (info, odom/reset, cmd/motion ...) and print its answer")
    p.add_argument("key", help="a queryable's name (info) or a full key")
    p.add_argument("json", nargs="?", help="the request as JSON (default: {})")
    p.add_argument("--timeout", type=float, default=5.0, metavar="S", help="wait this long for an answer")
