"""Verbs that listen and talk to a robot's bus: status, echo, hz, pub, query."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time
from collections import defaultdict
from collections.abc import Awaitable, Callable

import msgspec

from .. import graph
from ..config import RobotConfig
from ..errors import BadPayload, IcefloeError, UnknownKey
from ..runtime import Node, RawSample, run_async
from ..schemas import codec, keys
from .common import (
    Done,
    add_bus_arguments,
    add_key_argument,
    bus_config,
    check_robot,
    cli_node,
    decode_json,
    describe,
    drain_all,
    in_table,
    printable,
    resolve_key,
    subscribe_all,
    unknown_key,
    warn,
)

BusVerb = Callable[[argparse.Namespace, RobotConfig], Awaitable[int]]
NOTHING_HEARD = 1
"""Exit status of echo and hz when nothing arrived (a typo, or the service is not running)."""


def on_bus(verb: BusVerb) -> Callable[[argparse.Namespace], int]:
    """Run an async bus verb with the config its options name."""
    def run(args: argparse.Namespace) -> int:
        return run_async(verb(args, bus_config(args)))

    return run


def robot_of(args: argparse.Namespace, config: RobotConfig) -> str:
    return args.robot or config.name


async def look_before_listening(node: Node, key: str, typed: str, robot: str) -> None:
    """Say on stderr what would make a listener hear nothing: a robot that is not there, a key
    that is not in the key table (with the closest ones), a key nobody publishes."""
    alive, bus = await asyncio.gather(node.alive("*"), graph.read(node.session))
    if problem := check_robot(alive, robot):
        warn(problem)
    if not in_table(key):
        warn(unknown_key(key, typed) + "; listening anyway")
    me = str(node.session.info.zid())  # our own session declares a publisher on `log`
    if bus.routers and not [zid for zid in bus.on(key, "publisher") if zid != me]:
        warn(f"no publisher is declared on {key} now (`icefloe topics` lists what is published)")
    if sys.stderr.isatty():  # someone at a terminal: a quiet key (log on a robot at rest) prints nothing for long
        warn(f"listening on {key} (Ctrl-C stops)")


async def status(args: argparse.Namespace, config: RobotConfig) -> int:
    async with cli_node(config) as node:
        tokens = await node.alive(args.robot or "*")
    by_robot: dict[str, list[str]] = defaultdict(list)
    for token in tokens:
        _, robot, _, service = token.split("/", 3)
        if service not in by_robot[robot]:
            by_robot[robot].append(service)
    if not by_robot:
        print(f"robot {args.robot!r} is not alive on this bus" if args.robot else "no robot is alive on this bus")
        return 1
    for robot, services in sorted(by_robot.items()):
        print(f"{robot}: {' '.join(sorted(services))}")
    return 0


async def echo(args: argparse.Namespace, config: RobotConfig) -> int:
    robot = robot_of(args, config)
    key = resolve_key(args.key, robot)
    wildcard = "*" in key
    count = 1 if args.once else args.count
    seen = 0
    async with cli_node(config) as node:
        subs = subscribe_all(node, key)
        await look_before_listening(node, key, args.key, robot)

        def show(raw: RawSample) -> None:
            nonlocal seen
            try:
                text = json.dumps(describe(raw))
            except (BadPayload, msgspec.DecodeError, IcefloeError) as exc:
                text = json.dumps({"error": str(exc)})
            print(f"{raw.key} {text}" if wildcard else text, flush=True)
            seen += 1
            if count and seen >= count:
                raise Done

        await drain_all(subs, args.duration, show)
    if not seen and args.duration:
        warn(f"nothing on {key} within {args.duration:g} s")
        return NOTHING_HEARD
    return 0


async def hz(args: argparse.Namespace, config: RobotConfig) -> int:
    robot = robot_of(args, config)
    key = resolve_key(args.key, robot)
    total = 0
    async with cli_node(config) as node:
        subs = subscribe_all(node, key, maxsize=100_000)
        await look_before_listening(node, key, args.key, robot)
        end = time.monotonic() + (args.duration or float("inf"))
        while time.monotonic() < end:
            stamps: list[float] = []
            await drain_all(subs, min(args.window, max(end - time.monotonic(), 0.05)),
                            lambda raw, into=stamps: into.append(raw.received))
            stamps.sort()  # several subscriptions (`subscribe_all`): in the order received
            total += len(stamps)
            rate = (len(stamps) - 1) / (stamps[-1] - stamps[0]) if len(stamps) > 2 else 0.0
            print(f"{key}: {rate:.1f} Hz ({len(stamps)} messages in the last {args.window:g} s)", flush=True)
    if not total and args.duration:
        warn(f"nothing on {key} within {args.duration:g} s")
        return NOTHING_HEARD
    return 0


def publishable(key: str, typed: str, force: bool) -> keys.Topic | None:
    """The key-table row of a key one may publish to (None: outside the table, ``force``d), or an
    error naming what to do instead."""
    topic = keys.topic_of(key)
    inputs = ", ".join(t.name for t in keys.TABLE.values() if t.kind == "in")
    if topic is None:
        if force:
            return None
        raise UnknownKey(f"{unknown_key(key, typed)}; inputs are {inputs}; --force sends your JSON to it as it is")
    if topic.kind == "query":
        raise IcefloeError(f"{topic.name} is a queryable: ask it with `icefloe query {topic.name} JSON`")
    if topic.kind == "out" and not force:
        raise IcefloeError(f"{topic.name} is state the robot publishes ({topic.type.__name__}), not a command: "
                           f"publishing it would fake the robot's own data. Inputs are {inputs}; --force "
                           "publishes it anyway (a stand-in for a service, in a test)")
    return topic


async def pub(args: argparse.Namespace, config: RobotConfig) -> int:
    robot = robot_of(args, config)
    key = resolve_key(args.key, robot)
    if "*" in key:
        raise IcefloeError(f"{args.key}: one publishes to one key, not a wildcard")
    topic = publishable(key, args.key, args.force)
    message = decode_json(args.json, topic, key) if topic is not None else None
    if message is not None:
        payload, encoding = codec.encode(message), codec.MSGPACK
    else:
        try:
            msgspec.json.decode(args.json.encode())
        except msgspec.DecodeError as exc:
            raise BadPayload(f"{key}: not valid JSON: {exc}") from None
        payload, encoding = args.json.encode(), codec.JSON
    async with cli_node(config) as node:
        if problem := check_robot(await node.alive("*"), robot):
            warn(problem)
        # Declared, so `icefloe topics -v` counts us; a put of another robot's key goes as it is.
        publisher = node.publisher(topic) if topic is not None and key == node.key(topic) else None
        await asyncio.sleep(0.2)  # let the router learn our publisher before the first put
        period = 1.0 / args.rate if args.rate else 0.0
        if period and not args.count:
            print(f"publishing to {key} at {args.rate:g} Hz; Ctrl-C stops", file=sys.stderr, flush=True)
        sent = 0
        while True:
            if publisher is not None:
                publisher.put(message)
            else:
                node.session.put(key, payload, encoding=encoding)
            sent += 1
            if not period or (args.count and sent >= args.count):
                break
            await asyncio.sleep(period)
        await asyncio.sleep(0.1)
    return 0


async def query(args: argparse.Namespace, config: RobotConfig) -> int:
    robot = robot_of(args, config)
    key = resolve_key(args.key, robot)
    topic = keys.topic_of(key)
    if topic is None or topic.kind != "query":
        known = ", ".join(t.name for t in keys.TABLE.values() if t.kind == "query")
        what = unknown_key(key, args.key) if topic is None else f"{topic.name} is not a queryable"
        raise UnknownKey(f"{what}; the queryables are {known}")
    request = decode_json(args.json or "{}", topic, key)
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
    p = verb("echo", echo, "print a key's messages as JSON lines (Ctrl-C ends; exit 1 if nothing came)")
    add_key_argument(p, "a key-table name (odom/pose) or a full key; wildcards allowed (icefloe/*/odom/pose)")
    p.add_argument("-n", "--count", type=int, default=0, metavar="N", help="stop after N messages")
    p.add_argument("--once", action="store_true", help="print one message and stop (-n 1)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    p = verb("hz", hz, "the message rate of a key, once a window (exit 1 if nothing came)")
    add_key_argument(p, "a key-table name (hw/wheels) or a full key")
    p.add_argument("--window", type=float, default=1.0, metavar="S", help="report every S seconds (default 1)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    p = verb("pub", pub, "publish a message given as JSON to an input key (checked against its message first)")
    add_key_argument(p, "an input key (cmd/twist; `icefloe topics` lists them) or a full key")
    p.add_argument("json", metavar="JSON", help='the message as JSON, e.g. \'{"v": 0.1, "w": 0.5}\'; '
                                                "`icefloe info KEY` shows its fields")
    p.add_argument("--rate", type=float, default=0.0, metavar="HZ", help="repeat at this rate until Ctrl-C")
    p.add_argument("-n", "--count", type=int, default=0, metavar="N", help="with --rate: stop after N")
    p.add_argument("--force", action="store_true",
                   help="publish to a key that is not an input too (state the robot publishes, or a key "
                        "outside the key table, sent as the JSON given)")
    p = verb("query", query, "ask a queryable (info, odom/reset, cmd/motion ...) and print its answer")
    add_key_argument(p, "a queryable's name (info) or a full key")
    p.add_argument("json", metavar="JSON", nargs="?",
                   help="the request as JSON (default: {}); `icefloe info KEY` shows its fields")
    p.add_argument("--timeout", type=float, default=5.0, metavar="S", help="wait this long for an answer (default 5)")
