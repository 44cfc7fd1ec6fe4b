"""Verbs that explain a bus, as ``ros2 topic list/info``, ``ros2 node`` and ``ros2 interface`` do:
topics, info, services. Who declares what comes from the routers (icefloe/graph.py)."""

from __future__ import annotations

import argparse
import asyncio
from collections import defaultdict

from .. import graph
from ..config import RobotConfig
from ..errors import NotReachable, UnknownKey
from ..schemas import keys
from ..schemas.keys import Topic
from .bus import on_bus, robot_of
from .common import (
    add_bus_arguments,
    add_key_argument,
    cli_node,
    drain,
    message_fields,
    message_summary,
    resolve_key,
    unknown_key,
    warn,
)

KIND_ORDER = {"in": 0, "out": 1, "query": 2}
DIRECTION = {"in": "in: a command to the robot", "out": "out: state the robot publishes",
             "query": "query: a queryable (ask it, get one answer)"}
CLOSED = "(who declares what is unknown: the router's admin space is closed; icefloe's routers open it)"


def own_zid(node: object) -> str:
    return str(node.session.info.zid())  # type: ignore[attr-defined]


def names(bus: graph.Graph, zids: list[str], robot: str, me: str) -> list[str]:
    return [bus.name(z, robot) for z in zids if z != me]


async def topics(args: argparse.Namespace, config: RobotConfig) -> int:
    counts: dict[str, int] = defaultdict(int)
    async with cli_node(config) as node:
        alive = await node.alive(args.robot or "*")
        robots = [args.robot] if args.robot else sorted({keys.split(t)[0] for t in alive}) or [config.name]
        # Every key but camera/frames: subscribing to it would switch the camera's full-rate stream on.
        subs = [node.subscribe_raw(expr, maxsize=100_000) for expr in keys.all_but_frames(args.robot or "*")]
        await asyncio.gather(*(drain(sub, args.duration, lambda raw: counts.__setitem__(raw.key, counts[raw.key] + 1))
                               for sub in subs))
        bus = await graph.read(node.session)
        me = own_zid(node)
    rows = {keys.key(r, name) for r in robots for name in keys.TABLE}
    rows |= {k for k in counts if keys.split(k)[1].split("/")[0] != "alive"}
    for r in robots:
        rows |= bus.keys_declared(f"{keys.PREFIX}/{r}/")

    def order(key: str) -> tuple[str, int, str]:
        robot, name = keys.split(key)
        topic = keys.TABLE.get(name)
        return robot, KIND_ORDER[topic.kind] if topic else 3, name

    width = max(len(k) for k in rows)
    for key in sorted(rows, key=order):
        topic = keys.topic_of(key)
        kind, kind_name = (topic.kind, message_names(topic)) if topic else ("?", "?")
        rate = f"{counts[key] / args.duration:7.1f} Hz" if counts.get(key) else "       - " if kind != "query" else ""
        line = f"{key:<{width}}  {kind:<5}  {kind_name:<22} {rate:>10}"
        if args.verbose and bus.routers:
            robot = keys.split(key)[0]
            pubs, subs, qrys = (names(bus, bus.on(key, k), robot, me) for k in ("publisher", "subscriber", "queryable"))
            who = (f"answered by {', '.join(qrys)}" if qrys else "") if kind == "query" else \
                (f"{', '.join(pubs) or '-'} -> {', '.join(subs) or '-'}" if pubs or subs else "")
            line += f"  {len(pubs):>2} pub {len(subs):>2} sub {len(qrys):>2} qry  {who}"
        print(line.rstrip())
    if args.verbose and not bus.routers:
        print(CLOSED)
    return 0


def message_names(topic: Topic) -> str:
    """``Pose``; for a queryable, request and answer: ``PoseReset->Pose``."""
    return f"{topic.type.__name__}->{topic.reply.__name__}" if topic.reply else topic.type.__name__


def show_message(title: str, type_: type) -> None:
    print(f"{title}{type_.__name__}: {message_summary(type_)}")
    print("\n".join(message_fields(type_)))


async def info(args: argparse.Namespace, config: RobotConfig) -> int:
    robot = robot_of(args, config)
    key = resolve_key(args.key, robot)
    topic: Topic | None = keys.topic_of(key)
    if topic is not None:
        print(f"{key}  ({DIRECTION[topic.kind]})")
        if topic.kind == "query":
            show_message("request: ", topic.type)
            assert topic.reply is not None
            show_message("reply: ", topic.reply)
        else:
            show_message("", topic.type)
    try:
        async with cli_node(config) as node:
            bus = await graph.read(node.session)
            me = own_zid(node)
    except NotReachable as exc:
        if topic is None:
            raise UnknownKey(unknown_key(key, args.key)) from None
        warn(f"who publishes or answers it is unknown: {exc}")
        return 0
    found = {k: names(bus, bus.on(key, k), robot, me) for k in ("publisher", "subscriber", "queryable")}
    if topic is None:
        if not any(found.values()):
            raise UnknownKey(unknown_key(key, args.key))
        print(f"{key}  (not in the key table: its message is not known)")
    if not bus.routers:
        print(CLOSED)
        return 0
    labels = {"publisher": "publishers", "subscriber": "subscribers", "queryable": "answered by"}
    for kind, label in labels.items():
        if topic is not None and (kind == "queryable") != (topic.kind == "query") and not found[kind]:
            continue  # a topic has no queryables, a queryable no publishers: say so only if there are
        print(f"{label} ({len(found[kind])}): {', '.join(found[kind]) or '-'}")
    return 0


async def services(args: argparse.Namespace, config: RobotConfig) -> int:
    async with cli_node(config) as node:
        alive = await node.alive(args.robot or "*")
        bus = await graph.read(node.session)
        me = own_zid(node)
    by_name = {full: zid for zid, full in bus.names().items()}
    from_tokens = {f"{robot}/{name.removeprefix('alive/')}" for robot, name in map(keys.split, alive)}
    listed = sorted(from_tokens | set(by_name))
    if args.robot:
        listed = [n for n in listed if n.split("/", 1)[0] == args.robot]
    if args.service:
        listed = [n for n in listed if n.split("/", 1)[1] == args.service]
    if args.all:
        listed += [f"(unnamed {z[:8]})" for z in bus.by_session if z not in bus.names() and z != me]
    if not listed:
        what = f"service {args.service!r}" if args.service else "service"
        print(f"no {what} is alive on this bus" + (f" for robot {args.robot!r}" if args.robot else ""))
        return 1
    zid_of = {**by_name, **{f"(unnamed {z[:8]})": z for z in bus.by_session}}
    for name in listed:
        print(name)
        zid = zid_of.get(name)
        if name.endswith("/router"):
            print("  (the robot's Zenoh router: it routes everything and declares nothing)")
            continue
        if zid is None:
            print(f"  {CLOSED}" if not bus.routers else "  (declares nothing under icefloe/)")
            continue
        robot = name.split("/", 1)[0]
        decls = bus.by_session[zid]
        for kind, label in (("publisher", "publishes"), ("subscriber", "subscribes"), ("queryable", "answers")):
            shown = sorted(short(d.key_expr, robot) for d in decls if d.kind == kind)
            if shown:
                print(f"  {label + ':':<12} {', '.join(shown)}")
    return 0


def short(key_expr: str, robot: str) -> str:
    """A key as its name on ``robot`` (``odom/pose``), a full key expression otherwise."""
    prefix = f"{keys.PREFIX}/{robot}/"
    return key_expr.removeprefix(prefix) if key_expr.startswith(prefix) and "*" not in key_expr else key_expr


def register(verbs: argparse._SubParsersAction) -> None:
    def verb(name: str, run, help_: str) -> argparse.ArgumentParser:  # type: ignore[no-untyped-def]
        p = verbs.add_parser(name, help=help_, description=help_)
        add_bus_arguments(p)
        p.set_defaults(run=on_bus(run))
        return p

    p = verb("topics", topics, "every key of the key table and every key live on the bus: direction, "
                               "message, rate; -v: publishers, subscribers, queryables")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="also count (and name) the publishers, subscribers and queryables of each key")
    p.add_argument("--duration", type=float, default=2.0, metavar="S",
                   help="listen this long to measure the rates (default 2 s)")
    p = verb("info", info, "a key's message, field by field with units, and who publishes, subscribes "
                           "or answers it")
    add_key_argument(p, "a key-table name (odom/pose) or a full key")
    p = verb("services", services, "the services alive on the bus and the keys each publishes, subscribes "
                                   "to and answers")
    p.add_argument("service", metavar="SERVICE", nargs="?", help="only this service (e.g. hwbridge)")
    p.add_argument("-a", "--all", action="store_true",
                   help="also sessions without a name (tools, programs that hold no alive/<name> token)")
