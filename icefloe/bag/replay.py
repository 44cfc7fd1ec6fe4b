"""Replay: a recording published onto the bus with its original timing and encodings.

Each message goes out when its *receive* time in the file (the MCAP log time) comes round again,
scaled by ``rate``, with the Zenoh encoding and priority it had (`channels.payload`). Services
cannot tell a replay from a live robot: they see the same bytes, in the same order, with the same
stamps, at the same pace. What they compute from stamps (odometry from ``hw/wheels``, the
localizer's motion between poses) comes out the same; what depends on arrival time (which 20 ms
batch a sample lands in) may differ by a scheduling jitter, as it would between two live runs.

Safety: a recording with commands (``cmd/*``) is not replayed onto a robot that is live (its
``hwbridge`` holds a liveliness token) unless ``allow_commands``: recorded commands would move
real wheels. Replay under another name (``robot``) or leave them out (``exclude``).

Access control (docs/lab.md): a router with it passes on messages under ``icefloe/<robot>/`` only
from that robot's owner (its credentials), and drops the others without a word. So before the
first message the replay asks the router, from a second session, whether it took the replay's
liveliness token for each robot (the owner's rules allow the token and the messages, or neither),
and refuses in one line if not: a replay that reaches nobody is not silently "done".

The replay holds ``icefloe/<robot>/alive/replay-<pid>`` for each robot it replays, so tools that
find robots by their liveliness tokens (``icefloe status``, viz) see it; the pid tells two replays
apart (and the access check below asks for this replay's own token). With ``clock_hz`` it
publishes the recording's time on ``icefloe/<robot>/clock`` (`messages.Clock`).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import zenoh

from ..errors import BadRecording, IcefloeError
from ..runtime import LimitedLog, Node, open_session
from ..schemas import codec, keys
from ..schemas import messages as m
from .channels import ChannelPlan, payload
from .reader import Bag

START_DELAY_S = 0.3
"""Between declaring the publishers and the first message: time for the router to match them
with the subscribers, so the first messages are not sent to nobody."""
END_DELAY_S = 0.5
"""After the last message, before the session closes: Zenoh sends what is still queued (closing
the session drops it; large samples, camera images, are the last to go)."""
ALLOWED_TIMEOUT_S = 3.0
"""How long the router may take to show the replay's liveliness token to another session."""


@dataclass(frozen=True)
class ReplayOptions:
    rate: float = 1.0
    """Recorded seconds per second (2 = twice as fast)."""
    loop: bool = False
    start: float = 0.0
    """Seconds from the start of the recording."""
    end: float | None = None
    keys: Sequence[str] = ()
    """Only these keys: key-table names (hw/wheels), full keys or key expressions; empty = all."""
    exclude: Sequence[str] = ()
    clock_hz: float = 0.0
    """Publish the replay clock this often (0 = not at all)."""
    allow_commands: bool = False


@dataclass
class ReplayStats:
    sent: int = 0
    per_key: Counter[str] = field(default_factory=Counter)
    late_max: float = 0.0
    """The most a message went out after its time, s (a loaded machine, a blocked publisher)."""
    bad: int = 0
    """Messages that did not decode from the file, skipped."""
    passes: int = 0
    recorded: float = 0.0
    """Recording time replayed, s (last pass)."""
    started: float = field(default_factory=time.monotonic)


def selects(patterns: Sequence[str], key: str) -> bool:
    """Whether ``key`` matches one of ``patterns``: a key-table name or expression under any robot
    (``hw/wheels``, ``cmd/*``), or a full key expression (``icefloe/sim/**``)."""
    for pattern in patterns:
        exprs = [pattern] if pattern.startswith(keys.PREFIX + "/") else [f"{keys.PREFIX}/*/{pattern}", pattern]
        for expr in exprs:
            with contextlib.suppress(zenoh.ZError):
                if zenoh.KeyExpr(expr).intersects(key):
                    return True
    return False


def is_command(key: str) -> bool:
    topic = keys.topic_of(key)
    return topic is not None and topic.name.startswith("cmd/")


def choose(channels: Sequence[ChannelPlan], options: ReplayOptions) -> tuple[list[ChannelPlan], list[ChannelPlan]]:
    """(channels to replay, channels refused), after ``options.keys`` and ``options.exclude``."""
    chosen = [c for c in channels if (c.refused and not options.keys)  # a refused one has no key to select by
              or (not c.refused and (not options.keys or selects(options.keys, c.key))
                  and not selects(options.exclude, c.key))]
    return [c for c in chosen if not c.refused], [c for c in chosen if c.refused]


async def live_robots(node: Node, robots: set[str]) -> list[str]:
    """The robots among ``robots`` whose hwbridge is running (it holds its liveliness token)."""
    live = []
    for robot in sorted(robots):
        if keys.alive_key(robot, "hwbridge") in await node.alive(robot):
            live.append(robot)
    return live


async def check_commands(node: Node, channels: Sequence[ChannelPlan], options: ReplayOptions) -> None:
    """Refuse (IcefloeError) to replay commands onto a live robot unless ``options.allow_commands``."""
    commands = sorted({c.key for c in channels if is_command(c.key)})
    if not commands or options.allow_commands:
        return
    live = await live_robots(node, {keys.split(k)[0] for k in commands})
    if live:
        raise IcefloeError(
            f"not replaying: the recording has commands ({', '.join(commands)}) and robot {', '.join(live)} is "
            "live (its hwbridge is running): they would move its wheels. Replay under another name (--robot), "
            "leave them out (--exclude 'cmd/*'), or send them anyway (--allow-commands).")


def replay_service() -> str:
    """The service name of this replay's liveliness tokens: ``replay-<pid>``."""
    return f"replay-{os.getpid()}"


async def check_allowed(node: Node, robots: Sequence[str]) -> None:
    """Refuse (IcefloeError) unless the router passes on what this session publishes for ``robots``."""
    missing = list(robots)
    session = await open_session(node.config, log=node.log, retry=False)
    try:
        deadline = time.monotonic() + ALLOWED_TIMEOUT_S
        while missing and time.monotonic() < deadline:
            for robot in list(missing):
                token = keys.alive_key(robot, replay_service())
                replies = await asyncio.to_thread(lambda t=token: list(session.liveliness().get(t, timeout=1.0)))
                if any(r.ok is not None for r in replies):
                    missing.remove(robot)
            if missing:
                await asyncio.sleep(0.1)
    finally:
        session.close()
    if missing:
        names = ", ".join(missing)
        raise IcefloeError(
            f"not replaying: the router does not take messages for robot {names} from this session "
            f"(access control: only a robot's owner may publish under its name). Replay with that robot's "
            f"credentials (--credentials FILE), under the name of a robot you own (--robot NAME), or onto "
            f"a bus of your own (icefloe up on your laptop).")


class Publishers:
    """One Zenoh publisher per replayed key, with the priority its topic has on a live robot.

    Congestion control BLOCK: a slow subscriber slows the replay down (``late_max`` grows) rather
    than losing messages.
    """

    def __init__(self, session: zenoh.Session, channels: Sequence[ChannelPlan]) -> None:
        self._pubs: dict[tuple[str, str], zenoh.Publisher] = {}
        for channel in channels:
            topic = keys.topic_of(channel.key)
            urgent = topic is not None and topic.urgent
            self._pubs[(channel.key, channel.encoding)] = session.declare_publisher(
                channel.key, encoding=zenoh.Encoding(channel.encoding),
                congestion_control=zenoh.CongestionControl.BLOCK, express=urgent,
                priority=zenoh.Priority.REAL_TIME if urgent else zenoh.Priority.DEFAULT)

    def put(self, channel: ChannelPlan, data: bytes) -> None:
        self._pubs[(channel.key, channel.encoding)].put(data)

    def close(self) -> None:
        for pub in self._pubs.values():
            with contextlib.suppress(zenoh.ZError):
                pub.undeclare()


async def replay(node: Node, bag: Bag, options: ReplayOptions,
                 progress: Callable[[ReplayStats], None] | None = None) -> ReplayStats:
    """Publish ``bag`` onto ``node``'s bus as ``options`` say; returns what was sent."""
    if options.rate <= 0:
        raise IcefloeError(f"--rate must be > 0, got {options.rate}")
    channels, refused = choose(bag.channels(), options)
    for channel in refused:
        node.log.warning("not replaying %s: %s", channel.topic, channel.note)
    for channel in channels:
        if channel.note:
            node.log.warning("%s: %s", channel.topic, channel.note)
    if not channels:
        raise BadRecording(f"{bag.files[0].path}: nothing to replay (no channel left after the key selection)")
    await check_commands(node, channels, options)
    robots = sorted({keys.split(c.key)[0] for c in channels if c.key.startswith(keys.PREFIX + "/")})
    tokens = [node.session.liveliness().declare_token(keys.alive_key(r, replay_service())) for r in robots]
    publishers = Publishers(node.session, channels)
    stats = ReplayStats()
    wanted = set(channels)
    warn = LimitedLog(node.log)
    try:
        await asyncio.gather(check_allowed(node, robots), asyncio.sleep(START_DELAY_S))
        clock = Clock(node.session, robots, options)
        helpers = [asyncio.create_task(clock.run())] if options.clock_hz > 0 else []
        if progress is not None:
            helpers.append(asyncio.create_task(_report(progress, stats)))
        try:
            while True:
                stats.passes += 1
                await _one_pass(bag, wanted, options, publishers, stats, clock, warn)
                if not options.loop:
                    break
        finally:
            for task in helpers:  # the clock and the report end with the replay
                task.cancel()
            await asyncio.gather(*helpers, return_exceptions=True)
        await asyncio.sleep(END_DELAY_S)
    finally:
        publishers.close()
        for token in tokens:
            with contextlib.suppress(zenoh.ZError):
                token.undeclare()
    if progress is not None:
        progress(stats)
    return stats


async def _one_pass(bag: Bag, wanted: set[ChannelPlan], options: ReplayOptions, publishers: Publishers,
                    stats: ReplayStats, clock: Clock, warn: LimitedLog) -> None:
    loop = asyncio.get_running_loop()
    origin: int | None = None  # log time of the recording's first message, ns
    zero = begin = 0  # the pass's start: recording time (ns) and loop time (s)
    for entry in bag.entries():
        if origin is None:
            origin = entry.log_time
            begin = origin + int(options.start * 1e9)
            zero = loop.time()
            clock.start(begin, zero)
        if entry.log_time < begin or entry.channel not in wanted:
            continue
        offset = (entry.log_time - begin) * 1e-9
        if options.end is not None and offset + options.start > options.end:
            break
        due = zero + offset / options.rate
        wait = due - loop.time()
        if wait > 0:
            await asyncio.sleep(wait)
        else:
            stats.late_max = max(stats.late_max, -wait)
        try:
            data = payload(entry.channel, entry.data)
        except BadRecording as exc:
            stats.bad += 1
            warn.warning(str(exc))
            continue
        publishers.put(entry.channel, data)
        stats.sent += 1
        stats.per_key[entry.channel.key] += 1
        stats.recorded = offset


class Clock:
    """Publishes the recording's time at the play head on ``icefloe/<robot>/clock``."""

    def __init__(self, session: zenoh.Session, robots: Sequence[str], options: ReplayOptions) -> None:
        self._pubs = [session.declare_publisher(keys.key(r, keys.CLOCK), encoding=zenoh.Encoding(codec.MSGPACK))
                      for r in robots] if options.clock_hz > 0 else []
        self._options = options
        self._begin: int | None = None
        self._zero = 0.0

    def start(self, begin: int, zero: float) -> None:
        """A pass starts: recording time ``begin`` (ns) is loop time ``zero`` (s)."""
        self._begin, self._zero = begin, zero

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        period = 1.0 / self._options.clock_hz
        try:
            while True:
                if self._begin is not None:
                    now = self._begin + int((loop.time() - self._zero) * self._options.rate * 1e9)
                    data = codec.encode(m.Clock(stamp=now, rate=self._options.rate))
                    for pub in self._pubs:
                        pub.put(data)
                await asyncio.sleep(period)
        finally:
            for pub in self._pubs:
                with contextlib.suppress(zenoh.ZError):
                    pub.undeclare()


async def _report(progress: Callable[[ReplayStats], None], stats: ReplayStats) -> None:
    while True:
        await asyncio.sleep(0.5)
        progress(stats)
