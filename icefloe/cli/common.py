"""What the verb modules share: the robot/bus options, key names and their messages, printing samples."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import difflib
import sys
from collections.abc import Callable, Iterable
from typing import Any

import msgspec
import msgspec.inspect as mi
import zenoh

from .. import paths
from ..config import RobotConfig
from ..errors import BadPayload
from ..runtime import Node, RawSample, load_config
from ..schemas import codec, export, keys
from ..schemas.keys import Topic
from ..schemas.messages import Command, Message


def config_names(**_: object) -> list[str]:
    """Completion of a robot config: every name `icefloe.paths` resolves."""
    return paths.known("robots")


def key_names(prefix: str = "", **_: object) -> list[str]:
    """Completion of a KEY: the key table's names (and ``icefloe/...`` keys once one is typing them)."""
    names = list(keys.TABLE)
    if prefix.startswith(keys.PREFIX + "/"):
        robot = prefix.split("/")[1] if prefix.count("/") >= 2 else "sim"
        names = [keys.key(robot, n) for n in names]
    return [n for n in names if n.startswith(prefix)]


def add_config_argument(parser: argparse.ArgumentParser, *, positional: bool = False) -> None:
    """The robot a verb is about: ``CONFIG`` (positional) or ``--config``."""
    help_ = "robot config: a name (sim, penguin1) or a path to a .toml file (default: sim)"
    if positional:
        action = parser.add_argument("config", nargs="?", metavar="CONFIG", help=help_)
    else:
        action = parser.add_argument("--config", metavar="CONFIG", help=help_)
    action.completer = config_names  # type: ignore[attr-defined]


def add_key_argument(parser: argparse.ArgumentParser, help_: str, **kwargs: Any) -> None:
    """A KEY argument, completed from the key table."""
    action = parser.add_argument("key", metavar="KEY", help=help_, **kwargs)
    action.completer = key_names  # type: ignore[attr-defined]


def add_bus_arguments(parser: argparse.ArgumentParser,
                      robot_help: str = ("robot name on the bus: the <robot> of icefloe/<robot>/... "
                                         "(default: the config's name)")) -> argparse.ArgumentParser:
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
        data = msgspec.to_builtins(msg, builtin_types=(bytes,))
        if isinstance(msg, Command) and not (msg.sender or msg.seq or msg.stamp):
            for field in ("sender", "seq", "stamp"):  # not numbered: shown as it was sent
                del data[field]
        return printable(data)
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


async def drain_all(subs: list[Any], duration: float | None, handle: Callable[[RawSample], None]) -> None:
    """`drain` several subscriptions at once; all end when one ends (``duration``, or `Done`)."""
    tasks = [asyncio.ensure_future(drain(sub, duration, handle)) for sub in subs]
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


def subscribe_all(node: Any, key_expr: str, maxsize: int = 1024) -> list[Any]:
    """Raw subscriptions to ``key_expr``; "every key of a robot" (``icefloe/<robot>/**``) leaves
    ``camera/frames`` out (`keys.without_frames`: reaching it would switch the camera's full-rate
    stream on); name it to follow it."""
    return [node.subscribe_raw(expr, maxsize=maxsize) for expr in keys.without_frames(key_expr)]


# ---------------------------------------------------------------------- keys and their messages


def warn(text: str) -> None:
    print(f"icefloe: {text}", file=sys.stderr, flush=True)


def closest(key: str) -> list[str]:
    """Key-table names close to a mistyped key (its name part if it is a full key)."""
    if key.startswith(keys.PREFIX + "/"):
        try:
            robot, name = keys.split(key)
        except ValueError:
            return []
        return [keys.key(robot, n) for n in difflib.get_close_matches(name, list(keys.TABLE), n=3, cutoff=0.6)]
    return difflib.get_close_matches(key, list(keys.TABLE), n=3, cutoff=0.6)


def in_table(key_expr: str) -> bool:
    """Does the key expression reach a key of the key table on some robot?"""
    if "*" not in key_expr:
        return keys.topic_of(key_expr) is not None
    want = zenoh.KeyExpr(key_expr)
    return any(want.intersects(zenoh.KeyExpr(keys.key("*", name))) for name in keys.TABLE)


def unknown_key(key: str, typed: str) -> str:
    """The message for a key not in the key table, with the closest known ones."""
    near = closest(typed)
    hint = f" (did you mean {', '.join(near)}?)" if near else " (`icefloe topics` lists the keys)"
    return f"{typed}: not a key of the key table{hint}"


def type_name(t: mi.Type) -> str:
    """A msgspec type, as a student reads it: float, list[float], 'ok' | 'low' ..."""
    if isinstance(t, mi.ListType):
        return f"list[{type_name(t.item_type)}]"
    if isinstance(t, mi.LiteralType):
        return " | ".join(repr(v) for v in t.values)
    if isinstance(t, mi.StructType):
        return t.cls.__name__
    return {mi.IntType: "int", mi.FloatType: "float", mi.StrType: "str", mi.BoolType: "bool",
            mi.BytesType: "bytes"}.get(type(t), type(t).__name__.removesuffix("Type").lower())


STAMP_DOC = "ns since the Unix epoch (time.time_ns())"


def message_fields(type_: type[Message], indent: str = "  ") -> list[str]:
    """One line per field of a message: name, type, default, and what its docstring says (units);
    the fields of a nested message follow it, indented."""
    info = mi.type_info(type_)
    assert isinstance(info, mi.StructType)
    docs = export.field_docs()
    if not info.fields:
        return [f"{indent}(no fields: an empty map, or an empty payload)"]
    rows, nested = [], []
    for f in info.fields:
        default = ""
        if not f.required:
            value = f.default if f.default is not msgspec.NODEFAULT else f.default_factory()
            default = f" = {value!r}"
        doc = docs.get((type_.__name__, f.name)) or (STAMP_DOC if f.name == "stamp" else "")
        rows.append((f"{f.name}: {type_name(f.type)}{default}", " ".join(doc.split())))
        inner = f.type.item_type if isinstance(f.type, mi.ListType) else f.type
        if isinstance(inner, mi.StructType):
            nested.append(inner.cls)
    width = max(len(left) for left, _ in rows)
    lines = [f"{indent}{left:<{width}}  {doc}".rstrip() for left, doc in rows]
    for cls in nested:
        lines += [f"{indent}{cls.__name__}:", *message_fields(cls, indent + "  ")]
    return lines


def message_summary(type_: type[Message]) -> str:
    """The first line of a message's docstring."""
    return (type_.__doc__ or type_.__name__).strip().splitlines()[0]


def decode_json(text: str, topic: Topic, key: str) -> Message:
    """A message from the JSON a student typed; `BadPayload` that lists the message's fields."""
    try:
        return codec.decode(text.encode(), codec.JSON, topic.type, key)
    except BadPayload as exc:
        fields = "\n".join(message_fields(topic.type, "    "))
        raise BadPayload(f"{exc}\n  {topic.name} takes a {topic.type.__name__} as JSON, with these fields:\n"
                         f"{fields}\n  e.g. `icefloe info {topic.name}`") from None


def check_robot(alive: Iterable[str], robot: str) -> str | None:
    """A warning if nothing of ``robot`` is alive, naming the robots that are (from their tokens)."""
    robots = sorted({keys.split(t)[0] for t in alive})
    if "*" in robot or robot in robots:
        return None
    others = f"robots alive here: {', '.join(robots)}" if robots else "no robot is alive on this bus"
    return f"no service of robot {robot!r} is alive ({others}; --robot NAME picks one)"

