"""Verbs for recordings (MCAP files): record, replay, bag info, export. The work is in `icefloe.bag`."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import datetime
import logging
import os
import re
import signal
import socket
import sys
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, TextIO

import msgspec
import zenoh

from ..bag import Bag, BagWriter
from ..bag.replay import ReplayOptions, ReplayStats, replay
from ..bag.ros2 import Ros2BagWriter, Ros2Replay, Ros2Transcoder, require_ros2
from ..config import RobotConfig
from ..errors import BadRecording, IcefloeError
from ..runtime import Node, run_async
from ..schemas import keys
from .common import add_bus_arguments, bus_config, key_names, resolve_key

RECORD_QUEUE = 20_000
"""Samples the recorder holds between its callback and the file; beyond that the oldest are dropped
(and counted): the recorder's memory stays bounded whatever the disk does."""
TAKE_BATCH = 64
"""Samples written between two turns of the event loop when the recorder has a backlog."""
RECORD_NICE = 10
"""The recorder's niceness: on the robot, everything else runs first (hwbridge is real-time anyway)."""


# --------------------------------------------------------------------------- the live line


class Status:
    """A status line on stderr: rewritten in place on a terminal, one line every `every` s otherwise."""

    def __init__(self, stream: TextIO = sys.stderr, every: float = 10.0) -> None:
        self.stream = stream
        self.tty = stream.isatty()
        self.every = every
        self._last = 0.0

    def show(self, text: str, *, final: bool = False) -> None:
        now = time.monotonic()
        if self.tty:
            self.stream.write(f"\r\x1b[K{text}" + ("\n" if final else ""))
        elif final or now - self._last >= self.every:
            self.stream.write(text + "\n")
            self._last = now
        self.stream.flush()


def megabytes(n: int) -> str:
    return f"{n / 1e6:.2f} MB"


def parse_size(text: str) -> int:
    """Bytes from ``500k``, ``100M``, ``1.5G`` or a plain number (powers of 1000)."""
    match = re.fullmatch(r"\s*([0-9.]+)\s*([kKmMgG]?)[bB]?\s*", text)
    if not match:
        raise argparse.ArgumentTypeError(f"not a size: {text!r} (e.g. 500k, 100M, 2G)")
    scale = {"": 1, "k": 1e3, "m": 1e6, "g": 1e9}[match.group(2).lower()]
    return int(float(match.group(1)) * scale)


async def until_signal(work: Awaitable[int]) -> int:
    """Run ``work``; SIGINT or SIGTERM cancels it (its ``finally`` closes files), exit status 0."""
    task = asyncio.ensure_future(work)
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, task.cancel)
    try:
        return await task
    except asyncio.CancelledError:
        return 0
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)


def warnings_to_stderr() -> None:
    """Warnings of the bag library and the session (a truncated file, a channel not replayed) on stderr."""
    logging.basicConfig(stream=sys.stderr, level=logging.WARNING, format="%(message)s")


def on_bus(verb: Callable[[argparse.Namespace, RobotConfig], Awaitable[int]]) -> Callable[[argparse.Namespace], int]:
    def run(args: argparse.Namespace) -> int:
        warnings_to_stderr()
        return run_async(until_signal(verb(args, bus_config(args))))

    return run


# --------------------------------------------------------------------------- record


class KeyFilter:
    """Which subscription a key's samples are taken from (overlapping KEYS record a sample once)
    and whether ``--exclude`` leaves it out; decided once per key."""

    def __init__(self, patterns: list[str], excludes: list[str]) -> None:
        self._patterns = [zenoh.KeyExpr(p) for p in patterns]
        self._excludes = [zenoh.KeyExpr(e) for e in excludes]
        self._owner: dict[str, int] = {}

    def owner(self, key: str) -> int:
        found = self._owner.get(key)
        if found is None:
            if any(e.intersects(key) for e in self._excludes):
                found = -1
            else:
                found = next((i for i, p in enumerate(self._patterns) if p.intersects(key)), -1)
            self._owner[key] = found
        return found


def default_output(robot: str) -> Path:
    return Path(f"{robot}-{datetime.datetime.now():%Y%m%d-%H%M%S}.mcap")


class Recorder:
    """``icefloe record``'s work: samples from the subscriptions into the writer, and the live line."""

    def __init__(self, writer: BagWriter, keys_filter: KeyFilter) -> None:
        self.writer = writer
        self.keys_filter = keys_filter
        self.subs: list[Any] = []
        self.status = Status()
        self.start = time.monotonic()
        self._wall0, self._mono0 = time.time_ns(), time.monotonic()

    @property
    def dropped(self) -> int:
        return sum(s.skipped for s in self.subs)

    def line(self, verb: str = "recording") -> str:
        elapsed = time.monotonic() - self.start
        rate = self.writer.messages / elapsed if elapsed > 0 else 0.0
        lost = f", {self.dropped} dropped" if self.dropped else ""
        return (f"{verb} {self.writer.files[-1]}: {elapsed:6.1f} s  {self.writer.messages} messages  "
                f"{megabytes(self.writer.size)}  {rate:.0f} msg/s{lost}")

    def _write(self, index: int, raw: Any) -> None:
        if self.keys_filter.owner(raw.key) == index:
            log_time = self._wall0 + int((raw.received - self._mono0) * 1e9)  # receive time, ns
            self.writer.write(raw.key, raw.payload, raw.encoding, log_time)

    async def take(self, index: int, sub: Any) -> None:
        taken = 0
        async for raw in sub:
            self._write(index, raw)
            taken += 1
            if taken % TAKE_BATCH == 0 and sub.pending():
                # A subscription with a backlog hands out samples without ever waiting: let Ctrl-C,
                # --duration and the live line have their turn.
                await asyncio.sleep(0)

    async def drain(self) -> None:
        """Stop listening and write what was received before (Ctrl-C, --duration)."""
        for index, sub in enumerate(self.subs):
            sub.close()
            async for raw in sub:  # a closed subscription hands out what it holds, then ends
                self._write(index, raw)

    async def show(self) -> None:
        while True:
            await asyncio.sleep(0.5)
            self.writer.flush_if_due()  # a quiet bus still gets its chunks closed
            self.status.show(self.line())

    async def run(self, duration: float | None) -> None:
        """Until ``duration`` is up or cancelled; IcefloeError when the file cannot be written."""
        try:
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(duration), asyncio.TaskGroup() as tasks:
                    tasks.create_task(self.show())
                    for i, sub in enumerate(self.subs):
                        tasks.create_task(self.take(i, sub))
        except* OSError as group:  # the disk is full or gone: say so, keep what was written
            exc = group.exceptions[0]
            raise IcefloeError(f"{self.writer.files[-1]}: cannot write: {getattr(exc, 'strerror', '') or exc}; "
                               "the file holds what was written before") from None

    def close(self) -> None:
        with contextlib.suppress(OSError):  # after a write error: nothing more to save
            self.writer.close({"messages": str(self.writer.messages), "dropped": str(self.dropped),
                               "duration_s": f"{time.monotonic() - self.start:.3f}"})
        self.status.show(self.line("recorded"), final=True)


def ros2_recording(config: RobotConfig, robot: str, output: Path, **options: Any) -> Ros2BagWriter:
    """The writer of ``record --ros2``: the ros2 service's topics (its table, and ``cmd_vel``) in
    ROS 2's form, under the robot's ROS 2 namespace. A topic the service makes by asking a key
    (``map``: the grid is answered, not published) is not recorded."""
    from ..services.ros2 import convert  # numpy and rosbags' types: only for --ros2

    named = msgspec.structs.replace(config, name=robot)
    published = [output for output in convert.outputs(named) if output.request is None]
    outputs = [*published, convert.cmd_vel_output(named)]
    transcoder = Ros2Transcoder(outputs, robot, convert.ros_namespace(named), config.ros2.distro)
    return Ros2BagWriter(output, transcoder, **options)


def ros2_replay(config: RobotConfig) -> Ros2Replay:
    """What a replay turns back from ROS 2 topics into icefloe's keys (the ros2 service's table)."""
    from ..services.ros2 import convert

    return Ros2Replay(convert.inputs(config), config.ros2.distro)


async def record(args: argparse.Namespace, config: RobotConfig) -> int:
    robot = args.robot or config.name
    if args.ros2 and (args.keys or args.frames):
        raise IcefloeError("record --ros2 records the ros2 service's topics: no KEY arguments, no --frames")
    patterns = [resolve_key(k, robot) for k in args.keys]
    if args.frames:
        patterns = [*patterns, keys.key(robot, keys.FRAMES)] if patterns else [f"{keys.PREFIX}/{robot}/**"]
    shown = ", ".join(patterns)
    if not patterns:
        patterns = keys.all_but_frames(robot)
        shown = f"{keys.PREFIX}/{robot}/** but {keys.FRAMES.name} (--frames records it)"
    excludes = [resolve_key(k, robot) for k in args.exclude]
    try:
        keys_filter = KeyFilter(patterns, excludes)
    except zenoh.ZError as exc:
        raise IcefloeError(f"bad key expression: {exc}") from None
    if args.nice:
        os.nice(args.nice)  # before the session opens: Zenoh's threads inherit it
    output = Path(args.output) if args.output else default_output(robot)
    meta = {"robot": robot, "keys": shown, "exclude": " ".join(excludes),
            "started": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "host": socket.gethostname(), "command": " ".join(["icefloe", *sys.argv[1:]])}
    options: dict[str, Any] = {"compression": args.compression, "max_size": args.max_size, "metadata": meta}
    async with Node("record", config, announce=False, retry=False) as node:
        try:
            if args.ros2:
                bag = ros2_recording(config, robot, output, **options)
                patterns, output = bag.ros2.keys, bag.folder  # the table's keys only, into a rosbag2 folder
                keys_filter = KeyFilter(patterns, excludes)
                shown = ", ".join(f"{spec.topic} ({spec.schema_name})" for spec in bag.ros2.specs())
                writer: BagWriter = bag
            else:
                writer = BagWriter(output, **options)
        except OSError as exc:
            raise IcefloeError(f"{output}: cannot write: {exc.strerror or exc}") from None
        recorder = Recorder(writer, keys_filter)
        try:
            recorder.subs = [node.subscribe_raw(p, maxsize=RECORD_QUEUE) for p in patterns]
            print(f"recording {shown}" + (f" but {', '.join(excludes)}" if excludes else "") +
                  f" to {output} (Ctrl-C to stop)", file=sys.stderr, flush=True)
            try:
                await recorder.run(args.duration)
            finally:
                with contextlib.suppress(OSError):  # a full disk was reported already
                    await recorder.drain()
        finally:
            recorder.close()
    return 0


# --------------------------------------------------------------------------- replay


async def replay_verb(args: argparse.Namespace, config: RobotConfig) -> int:
    bag = Bag(args.files, robot=args.robot, ros2=ros2_replay(config))
    if args.ros2:
        require_ros2(bag)
    options = ReplayOptions(rate=args.rate, loop=args.loop, start=args.start, end=args.end, keys=args.keys or (),
                            exclude=args.exclude or (), clock_hz=args.clock, allow_commands=args.allow_commands)
    status = Status()

    def progress(stats: ReplayStats) -> None:
        status.show(f"replaying {bag.files[0].path}: {stats.recorded:6.1f} s of the recording, {stats.sent} messages, "
                    f"late at most {stats.late_max * 1e3:.0f} ms" + (f", pass {stats.passes}" if args.loop else ""))

    async with Node("replay", config, announce=False, retry=False) as node:
        stats = await replay(node, bag, options, progress)
    status.show(f"replayed {stats.sent} messages on {len(stats.per_key)} keys in "
                f"{time.monotonic() - stats.started:.1f} s; late at most {stats.late_max * 1e3:.0f} ms"
                + (f"; {stats.bad} did not decode" if stats.bad else ""), final=True)
    return 0


# --------------------------------------------------------------------------- bag info, export


def info(args: argparse.Namespace) -> int:
    # ROS 2 topics shown as replay takes them (the default distro's types: these types are the same in each)
    bag = Bag(args.files, ros2=ros2_replay(RobotConfig()))
    counts: dict[tuple[str, str, str], list[int]] = {}  # (key, form, encoding) -> [count, first, last]
    notes: dict[tuple[str, str, str], str] = {}
    for entry in bag.entries():
        c = entry.channel
        row = counts.setdefault((c.key or c.topic, c.form, c.encoding), [0, entry.log_time, entry.log_time])
        row[0] += 1
        row[1], row[2] = min(row[1], entry.log_time), max(row[2], entry.log_time)
        notes[(c.key or c.topic, c.form, c.encoding)] = ("refused: " if c.refused else "") + c.note
    meta = bag.metadata().get("icefloe", {})
    total = sum(r[0] for r in counts.values())
    first = min((r[1] for r in counts.values()), default=0)
    last = max((r[2] for r in counts.values()), default=0)
    for state in bag.files:
        whole = "" if state.whole else ", truncated"
        print(f"file:      {state.path} ({megabytes(state.size)}, {state.compression or 'uncompressed'}, "
              f"{state.chunks} chunks{whole})")
    if meta:
        print(f"recorded:  robot {meta.get('robot', '?')} on {meta.get('host', '?')}, {meta.get('started', '?')}")
    if first:
        start = datetime.datetime.fromtimestamp(first / 1e9).astimezone()
        print(f"start:     {start.isoformat(timespec='milliseconds')}")
    print(f"duration:  {(last - first) / 1e9:.3f} s")
    end = bag.metadata(len(bag.files) - 1).get("icefloe.end", {})
    dropped = f" ({end['dropped']} dropped by the recorder)" if end.get("dropped", "0") != "0" else ""
    print(f"messages:  {total}{dropped}")
    width = max((len(k[0]) for k in counts), default=10)
    print(f"\n{'key':<{width}}  {'count':>7}  {'rate':>8}  form   encoding")
    for (key, form, encoding), (n, t0, t1) in sorted(counts.items()):
        rate = (n - 1) / ((t1 - t0) / 1e9) if n > 1 and t1 > t0 else 0.0
        note = notes[(key, form, encoding)]
        print(f"{key:<{width}}  {n:>7}  {rate:>5.1f} Hz  {form:<5}  {encoding}" + (f"  ({note})" if note else ""))
    return 0


def export(args: argparse.Namespace) -> int:
    from ..bag.export import to_csv

    written = to_csv(Bag(args.files), args.csv)
    for path, rows in sorted(written.items()):
        print(f"{path}: {rows} rows")
    return 0


def guarded(verb: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """A file verb whose OSErrors (no such file, no space) are reported like the others."""
    def run(args: argparse.Namespace) -> int:
        warnings_to_stderr()
        try:
            return verb(args)
        except OSError as exc:
            raise BadRecording(f"{exc.filename or ''}: {exc.strerror or exc}") from None

    return run


# --------------------------------------------------------------------------- the parsers


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("record", help="record a robot's keys into an MCAP file (Ctrl-C to stop)",
                         description="Record a robot's bus into an MCAP file: one channel per key, JSON Schema + "
                         "JSON (Foxglove opens it as it is). Runs at low priority; Ctrl-C closes a valid file.")
    add_bus_arguments(p, robot_help="the robot to record (default: the config's)")
    keys_arg = p.add_argument("keys", nargs="*", metavar="KEY", help="key-table names (hw/wheels), full keys or "
                              "key expressions (default: every key of the robot but camera/frames)")
    keys_arg.completer = key_names  # type: ignore[attr-defined]
    p.add_argument("-o", "--output", metavar="FILE.mcap", help="the file (default: <robot>-<date>-<time>.mcap)")
    p.add_argument("--frames", action="store_true",
                   help="record camera/frames too (every captured frame, ~300 KB/s: the camera sends it "
                   "only while something subscribes)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--exclude", action="append", default=[], metavar="KEY",
                   help="leave out these keys (repeatable; e.g. camera/image)")
    p.add_argument("--max-size", type=parse_size, default=0, metavar="SIZE",
                   help="split into numbered files of about SIZE (500M, 2G): FILE_000.mcap, FILE_001.mcap ...")
    p.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd", help="chunk compression")
    p.add_argument("--ros2", action="store_true",
                   help="record the robot's ROS 2 topics as the ros2 service publishes them (odom, ..., and "
                   "cmd_vel from cmd/twist) into a rosbag2 folder: metadata.yaml and FOLDER_0.mcap in ROS 2's "
                   "form (ros2msg schemas, CDR), which ros2 bag, rosbags and Foxglove read")
    p.add_argument("--nice", type=int, default=RECORD_NICE, metavar="N",
                   help=f"lower the recorder's CPU priority by N (default {RECORD_NICE})")
    p.set_defaults(run=on_bus(record))

    p = verbs.add_parser("replay", help="publish a recording onto the bus with its original timing",
                         description="Publish an MCAP recording onto the bus with its original timing and "
                         "encodings, so services see it as live. Refuses to send commands (cmd/*) to a live robot.")
    add_bus_arguments(p, robot_help="replay under this robot name (default: the recorded one)")
    p.add_argument("files", nargs="+", metavar="FILE.mcap", help="the recording (several: a split one, in order)")
    p.add_argument("--rate", type=float, default=1.0, help="speed: 2 = twice as fast (default 1)")
    p.add_argument("--loop", action="store_true", help="start again at the end, until Ctrl-C")
    p.add_argument("--start", type=float, default=0.0, metavar="S", help="begin S seconds into the recording")
    p.add_argument("--end", type=float, metavar="S", help="stop S seconds into the recording")
    keys_arg = p.add_argument("--keys", nargs="+", metavar="KEY",
                              help="only these keys (hw/wheels camera/landmarks, cmd/*)")
    keys_arg.completer = key_names  # type: ignore[attr-defined]
    p.add_argument("--exclude", action="append", metavar="KEY", help="leave out these keys (repeatable)")
    p.add_argument("--clock", type=float, nargs="?", const=100.0, default=0.0, metavar="HZ",
                   help="publish the recording's time on <robot>/clock (default 100 Hz)")
    p.add_argument("--ros2", action="store_true",
                   help="the recording must be a ROS 2 one (record --ros2, ros2 bag -s mcap): refuse another")
    p.add_argument("--allow-commands", action="store_true",
                   help="replay cmd/* even when the robot is live (its hwbridge runs): it will move")
    p.set_defaults(run=on_bus(replay_verb))

    p = verbs.add_parser("bag", help="look at a recording: bag info FILE",
                         description="Look at an MCAP recording without a bus.")
    bag_verbs = p.add_subparsers(dest="bag_verb", required=True, metavar="VERB", help="info")
    q = bag_verbs.add_parser("info", help="keys, counts, rates, duration and size of a recording",
                             description="Keys, counts, rates, duration and size of a recording (a truncated "
                             "one is read up to its last whole chunk, with one warning).")
    q.add_argument("files", nargs="+", metavar="FILE.mcap", help="the recording (several: a split one, in order)")
    q.set_defaults(run=guarded(info))

    p = verbs.add_parser("export", help="a recording as CSV files, one per key",
                         description="A recording as CSV files, one per key (log_time, then the message's fields; "
                         "camera images as JPEG files beside them), for a homework without icefloe running.")
    p.add_argument("files", nargs="+", metavar="FILE.mcap", help="the recording (several: a split one, in order)")
    p.add_argument("--csv", required=True, metavar="DIR", help="write one CSV per key into DIR")
    p.set_defaults(run=guarded(export))
