"""The service runtime: what every icefloe process is built on.

A service looks like this (see ``services/odometry/`` for a real one)::

    async def main(config: RobotConfig) -> None:
        async with Node("echo", config) as node:
            pose = node.publisher(keys.ODOM_POSE)
            async for wheels in node.subscribe(keys.WHEELS):
                pose.put(...)

    if __name__ == "__main__":
        run(main)

What it gives you:

* `Node`: one Zenoh session per process, opened from the robot config (client of
  the robot's router, no multicast), a liveliness token ``alive/<service>``, a
  logger that writes to stderr and to the bus key ``log``. Closing the node
  closes the session, so the process really ends.
* Typed subscriptions as async iterators. Zenoh hands each sample to a thread of
  ours (`deliver_on_thread`), which only stores the raw sample and wakes the event
  loop (`LoopWakeup`: a write to an eventfd the loop watches, one for all the
  samples that came since the loop last looked). Decoding happens in the loop. Each subscription
  has a queue policy: *latest* (keep only the newest sample: sensor streams) or
  *fifo* (keep up to ``maxsize`` in order, dropping the oldest: commands). Bad
  payloads are dropped with a log line naming the key and the field.
  `Node.batches` reads a high-rate stream once per period instead (a list of
  messages each time), without running Python on Zenoh's thread per sample;
  `Node.latest` keeps only the newest, decoded when asked for.
* Typed publishers, queryables with async handlers, and `Node.query`.
* `run`: the ``__main__`` of every service: ``--config``, ``--connect``, logging,
  and a clean exit on SIGINT/SIGTERM.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import os
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Awaitable, Callable, Coroutine, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Generic, TypeVar

import msgspec
import zenoh

from . import config as config_mod
from .config import RobotConfig
from .credentials import GUEST_PASSWORD, GUEST_USER
from .errors import EXIT_CONFIG, BadPayload, ConfigError, IcefloeError, NotReachable
from .logs import LimitedLog, printable
from .schemas import codec, keys
from .schemas.keys import Topic
from .schemas.messages import Command, Log, Message

T = TypeVar("T", bound=Message)
T2 = TypeVar("T2")
C = TypeVar("C", bound=Command)
MSGPACK = zenoh.Encoding(codec.MSGPACK)
JSON = zenoh.Encoding(codec.JSON)
MAX_QUERIES = 32
"""Queries one queryable answers at once (`Node.queryable`)."""
BUS_LOG_RATE = 20.0
"""Log lines a service copies to the bus key ``log`` per second, on average (`_BusLogHandler`)."""
BUS_LOG_BURST = 50
"""... and at most this many at once."""


def zenoh_config(
    config: RobotConfig,
    *,
    mode: str = "client",
    connect: Sequence[str] | None = None,
    listen: Sequence[str] | None = None,
    guest: bool = False,
) -> zenoh.Config:
    """Zenoh config of a session: no multicast scouting, credentials from the robot config.

    Without a user of its own, a session to a robot with access control logs in as the
    read-only `guest` (see icefloe/credentials.py).
    """
    zc = zenoh.Config()
    if config.zenoh.config and mode == "router":
        zc = zenoh.Config.from_file(config.zenoh.config)
    zc.insert_json5("mode", json.dumps(mode))
    zc.insert_json5("scouting/multicast/enabled", "false")
    zc.insert_json5("connect/endpoints", json.dumps(list(connect or [])))
    zc.insert_json5("listen/endpoints", json.dumps(list(listen or [])))
    z = config.zenoh
    if mode == "router" and z.tls_certificate:
        zc.insert_json5("transport/link/tls/listen_certificate", json.dumps(z.tls_certificate))
        zc.insert_json5("transport/link/tls/listen_private_key", json.dumps(z.tls_private_key))
    if z.tls_root_ca:
        zc.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(z.tls_root_ca))
    user, password = config.zenoh.user, config.zenoh.password
    if not user and (guest or config.zenoh.access_control):
        user, password = GUEST_USER, GUEST_PASSWORD
    if user:
        zc.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
        zc.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    return zc


READER_JOIN_TIMEOUT = 2.0
"""How long closing a subscription or node waits for its reader thread to end, s."""


def deliver_on_thread(handler: Any, deliver: Callable[[Any], object], name: str,
                      warn: LimitedLog) -> threading.Thread:
    """Call ``deliver`` with each sample (or query) that Zenoh puts in ``handler`` (the channel of
    a subscriber or queryable declared with ``zenoh.handlers.DefaultHandler()``), one by one, on
    a thread of our own; the thread ends when the subscriber is undeclared or its session closed.
    Join it after that (`Subscription.close`, `Node.close`).

    Why not hand zenoh-python the callback? It would run it on a thread it starts itself, the
    same way, but one we cannot join: declared from a daemon thread (the blocking `Robot`'s
    event loop) that thread is a daemon too, and when the interpreter exits while it is still
    inside Zenoh, the process aborts ("FATAL: exception not rethrown") instead of exiting."""

    def read() -> None:
        for item in handler:
            try:
                deliver(item)
            except Exception as exc:  # one bad sample must not end the subscription (nor flood the log)
                warn.warning(f"deliver {name}", "%s: delivering a sample failed", name, exc_info=exc)

    thread = threading.Thread(target=read, name=name, daemon=True)
    thread.start()
    return thread


def join_reader(thread: threading.Thread, log: logging.Logger) -> None:
    """Wait for a `deliver_on_thread` thread whose subscriber or session was just closed."""
    if thread is not threading.current_thread():
        thread.join(READER_JOIN_TIMEOUT)
        if thread.is_alive():
            log.warning("%s still running %.0f s after its subscription closed", thread.name,
                        READER_JOIN_TIMEOUT)


@dataclass(frozen=True)
class RawSample:
    """A sample as it came off the bus (for tools that handle any key)."""

    key: str
    payload: bytes
    encoding: str
    received: float
    """time.monotonic() when the callback saw it."""


class LoopWakeup:
    """Wakes an event loop from other threads: after `signal`, the loop runs ``callback``.

    `signal` writes to a file descriptor the loop watches (``add_reader``: an eventfd on Linux,
    else a pipe), and only when no wake-up is pending already: samples that come before the
    loop looks share one. ``os.write`` lets go of the GIL before the system call, so the loop
    wakes to a free GIL (with ``call_soon_threadsafe`` it woke while the signalling thread still
    held it, and slept again until it let go), and the callback runs as soon as the loop sees
    the descriptor ready, one loop iteration before a ``call_soon_threadsafe`` callback would
    (docs/runtime.md). Where the loop watches no descriptors (Windows' proactor loop) it is
    ``call_soon_threadsafe``."""

    def __init__(self, loop: asyncio.AbstractEventLoop, callback: Callable[[], object]) -> None:
        self._loop, self._callback = loop, callback
        self._signalled = False
        if hasattr(os, "eventfd"):
            self._read_fd = self._write_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        else:
            self._read_fd, self._write_fd = os.pipe()
            os.set_blocking(self._read_fd, False)
            os.set_blocking(self._write_fd, False)
        try:
            loop.add_reader(self._read_fd, self._woken)
        except NotImplementedError:
            self._close_fds()

    # `signal` and `_woken` run once per sample, each on a thread that was asleep until then,
    # where every line costs several times what it costs in a warm loop (docs/runtime.md): they
    # are short, and use try where contextlib.suppress would cost more.

    def signal(self) -> None:
        """Any thread: have the loop run the callback (once for all signals since it last did)."""
        if self._signalled:
            return
        self._signalled = True
        if self._write_fd >= 0:
            try:  # noqa: SIM105
                os.write(self._write_fd, b"\1\0\0\0\0\0\0\0")  # an eventfd takes 8 bytes; a pipe any
            except OSError:  # closed (its subscription is): nobody to wake
                pass
        else:
            try:  # noqa: SIM105
                self._loop.call_soon_threadsafe(self._woken)
            except RuntimeError:  # the loop is closing: nothing to wake
                pass

    def _woken(self) -> None:
        # Empty the descriptor before clearing the flag: a signal after this writes anew.
        if self._read_fd >= 0:
            try:  # noqa: SIM105
                os.read(self._read_fd, 64)
            except OSError:
                pass
        self._signalled = False
        self._callback()

    def close(self) -> None:
        """In the loop, once no thread signals any more (idempotent)."""
        if self._read_fd >= 0:
            with contextlib.suppress(Exception):  # the loop may be closed already
                self._loop.remove_reader(self._read_fd)
            self._close_fds()

    def _close_fds(self) -> None:
        for fd in {self._read_fd, self._write_fd}:
            os.close(fd)
        self._read_fd = self._write_fd = -1


class Subscription(Generic[T]):
    """An async iterator over the messages of one key expression.

    Zenoh puts each sample in the subscriber's channel; a reader thread of ours
    (`deliver_on_thread`) takes it out, queues its key, bytes and encoding, and wakes the loop
    (`LoopWakeup`) unless a wake-up is on its way already. The loop decodes. Why a thread of
    ours and not Zenoh's own: `deliver_on_thread`."""

    def __init__(self, node: Node, key_expr: str, type_: type[T] | None, *, latest: bool, maxsize: int) -> None:
        """``type_``: the messages, taken on their own key only (`Node.own_key`); None:
        `RawSample` s of any key."""
        self.key_expr = key_expr
        self.latest = latest
        self.skipped = 0
        """Samples overwritten (latest) or dropped because the queue was full (fifo)."""
        self.rejected = 0
        """Samples dropped because they did not decode, or came on a wildcard (`Node.own_key`)."""
        self._node = node
        self._type = type_
        self._msgpack = msgspec.msgpack.Decoder(type_) if type_ is not None else None
        self._items: deque[tuple[str, bytes, str, float]] = deque(maxlen=1 if latest else maxsize)
        self._loop = asyncio.get_running_loop()
        self._waiters: list[asyncio.Future[None]] = []
        """Of the tasks waiting for a sample (one, unless several read this subscription)."""
        self._wakeup = LoopWakeup(self._loop, self._woken)
        self._closed = False
        self._warn, self._kind = node.limited, node.short(key_expr)
        self._key = zenoh.KeyExpr(key_expr)
        self._sub = node.session.declare_subscriber(self._key, zenoh.handlers.DefaultHandler())
        self._reader = deliver_on_thread(self._sub.handler, self._on_sample, f"icefloe {key_expr}", node.limited)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        # Our reader thread: copy the bytes, queue them (a full queue drops its oldest), wake the
        # loop. Never block: meanwhile Zenoh queues the samples behind (past 256 it waits). Each
        # call into zenoh-python costs here (`LoopWakeup`): comparing the key and the encoding
        # with ours costs less than making strings of them, which only the others need.
        items = self._items
        if len(items) == items.maxlen:
            self.skipped += 1
        key, encoding = sample.key_expr, sample.encoding
        items.append((self.key_expr if key == self._key else str(key), sample.payload.to_bytes(),
                      codec.MSGPACK if encoding == MSGPACK else str(encoding), time.monotonic()))
        self._wakeup.signal()

    def __aiter__(self) -> Subscription[T]:
        return self

    async def __anext__(self) -> T:
        items = self._items
        while True:
            try:
                key, payload, encoding, received = items.popleft()
            except IndexError:
                if self._closed:
                    raise StopAsyncIteration from None
                # Every sample queued from here on is followed by a wake-up (`LoopWakeup`).
                waiter = self._loop.create_future()
                self._waiters.append(waiter)
                try:
                    if not items:
                        await waiter
                finally:
                    self._waiters.remove(waiter)
                continue
            # What `Node.own_key` and `codec.decode` do, the common case inline: this runs per sample.
            if self._type is None:
                return RawSample(key, payload, encoding, received)  # type: ignore[return-value]
            if "*" in key and not self._node.own_key(self.key_expr, key):
                self.rejected += 1
                continue
            if encoding is codec.MSGPACK:  # what every service sends (`_on_sample`)
                try:
                    return self._msgpack.decode(payload)  # type: ignore[union-attr]
                except (msgspec.DecodeError, UnicodeDecodeError):
                    pass  # codec.decode says what is wrong (an empty payload is an empty map)
            try:
                return codec.decode(payload, encoding, self._type, key)
            except BadPayload as exc:
                self.rejected += 1
                self._warn.warning(self._kind, "dropped: %s", exc)

    def _woken(self) -> None:  # the loop, woken by our reader thread (or closing)
        for waiter in self._waiters:
            if not waiter.done():
                waiter.set_result(None)

    def pending(self) -> int:
        """Samples queued and not yet read."""
        return len(self._items)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            with contextlib.suppress(zenoh.ZError):  # its session is closed already
                self._sub.undeclare()
            join_reader(self._reader, self._node.log)
            if not self._reader.is_alive():  # else its pipe stays open: the thread may still write
                self._wakeup.close()
            self._woken()


class Batches(Generic[T]):
    """An async iterator that yields, once every ``period`` seconds, the list of messages of one
    key that arrived since the previous list (oldest first; empty when none came).

    For high-rate streams read by a slower loop (1 kHz wheels into 50 Hz odometry). No Python
    runs per sample on Zenoh's thread: Zenoh keeps the samples in its own ring (the newest
    ``maxsize``) and each period the loop takes them all at once. Periods follow absolute
    deadlines; a late one is not followed by a burst.
    """

    def __init__(self, node: Node, key_expr: str, decode: Callable[[bytes, str, str], T], *,
                 period: float, maxsize: int) -> None:
        self.key_expr = key_expr
        self.period = period
        self.rejected = 0
        """Samples dropped because they did not decode, or came on a wildcard (`Node.own_key`)."""
        self._node = node
        self._decode = decode
        self._deadline: float | None = None
        self._closed = False
        self._warn, self._kind = node.limited, node.short(key_expr)
        self._sub = node.session.declare_subscriber(key_expr, zenoh.handlers.RingChannel(maxsize))

    def __aiter__(self) -> Batches[T]:
        return self

    async def __anext__(self) -> list[T]:
        loop = asyncio.get_running_loop()
        now = loop.time()
        if self._deadline is None or self._deadline < now - self.period:
            self._deadline = now  # first period, or we fell behind: start again from now
        self._deadline += self.period
        await asyncio.sleep(self._deadline - now)
        if self._closed:
            raise StopAsyncIteration
        return self.take()

    def take(self) -> list[T]:
        """The messages that arrived since the last list, now, without waiting."""
        batch: list[T] = []
        while (sample := self._sub.try_recv()) is not None:
            key = str(sample.key_expr)
            if not self._node.own_key(self.key_expr, key):
                self.rejected += 1
                continue
            try:
                batch.append(self._decode(sample.payload.to_bytes(), str(sample.encoding), key))
            except BadPayload as exc:
                self.rejected += 1
                self._warn.warning(self._kind, "dropped: %s", exc)
        return batch

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._sub.undeclare()


class Latest(Generic[T]):
    """The newest message of one key, read when you ask for it (`get`).

    For a state stream that a slow loop only looks at now and then (the little screen's wheel
    speeds, at 50 Hz, shown five times a second): Zenoh keeps the newest sample in a ring of
    one, and no Python runs per sample; `get` decodes only a sample that is new."""

    def __init__(self, node: Node, key_expr: str, decode: Callable[[bytes, str, str], T]) -> None:
        self.key_expr = key_expr
        self.value: T | None = None
        """The newest message `get` has seen (None until one came)."""
        self.rejected = 0
        """Samples dropped because they did not decode, or came on a wildcard (`Node.own_key`)."""
        self._node, self._decode = node, decode
        self._warn, self._kind = node.limited, node.short(key_expr)
        self._sub = node.session.declare_subscriber(key_expr, zenoh.handlers.RingChannel(1))

    def get(self) -> T | None:
        """The newest message that came, or None if none came yet."""
        sample = self._sub.try_recv()
        if sample is not None:
            key = str(sample.key_expr)
            if not self._node.own_key(self.key_expr, key):
                self.rejected += 1
            else:
                try:
                    self.value = self._decode(sample.payload.to_bytes(), str(sample.encoding), key)
                except BadPayload as exc:
                    self.rejected += 1
                    self._warn.warning(self._kind, "dropped: %s", exc)
        return self.value

    def undeclare(self) -> None:
        """Stop following the key; the node forgets this one too (a service that follows a key
        only while it needs it may do so again and again: the oled service's screens)."""
        self._sub.undeclare()
        with contextlib.suppress(ValueError):  # already forgotten
            self._node._closables.remove(self)


class Publisher(Generic[T]):
    """Publishes one message type on one key, as MessagePack."""

    def __init__(self, node: Node, topic: Topic, *, express: bool = False, robot: str | None = None) -> None:
        self.key_expr = keys.key(robot or node.robot, topic)
        self._type = topic.type
        self._pub = node.session.declare_publisher(
            self.key_expr,
            encoding=MSGPACK,
            congestion_control=zenoh.CongestionControl.DROP,
            express=express or topic.urgent,
            priority=zenoh.Priority.REAL_TIME if topic.urgent else zenoh.Priority.DEFAULT,
        )

    @property
    def matched(self) -> bool:
        """Does a subscriber match this key now (Zenoh's matching status)? A publisher whose
        messages are costly to make makes them only then (the camera's ``camera/frames``)."""
        return bool(self._pub.matching_status.matching)

    def put(self, message: T) -> None:
        if type(message) is not self._type:
            raise TypeError(f"{self.key_expr} carries {self._type.__name__}, not {type(message).__name__}")
        self._pub.put(codec.encode(message))


def _decoder(topic: Topic) -> Callable[[bytes, str, str], Any]:
    """``decode(payload, encoding, key)`` into ``topic``'s message, as `codec.decode` does; a
    MessagePack payload (what every service sends) goes straight to msgspec, and only one that
    fails goes through `codec.decode`, which says what is wrong (`BadPayload`)."""
    type_ = topic.type
    msgpack = msgspec.msgpack.Decoder(type_)

    def decode(payload: bytes, encoding: str, key: str) -> Any:
        if encoding == codec.MSGPACK:
            try:
                return msgpack.decode(payload)
            except (msgspec.DecodeError, UnicodeDecodeError):
                pass  # an empty payload is an empty map, and the others get their line: codec.decode
        return codec.decode(payload, encoding, type_, key)

    return decode


def decode_query(query: zenoh.Query, kind: type[T], key_expr: str) -> T:
    """A query's request as a ``kind`` message; `BadPayload` naming ``key_expr`` if it is not one."""
    payload = query.payload.to_bytes() if query.payload is not None else b""
    encoding = str(query.encoding) if query.encoding is not None else ""
    return codec.decode(payload, encoding, kind, key_expr)


class Node:
    """One service's connection to the bus. Use as ``async with Node(name, config) as node``."""

    def __init__(self, service: str, config: RobotConfig, *, mode: str = "client",
                 announce: bool = True, retry: bool = True, one_zenoh_thread: bool = True) -> None:
        """``announce``: hold the liveliness token; ``retry``: wait for the router instead of
        raising `NotReachable` (services wait; command-line tools fail fast);
        ``one_zenoh_thread``: `SERVICE_ZENOH_RUNTIME` (False: Zenoh's own pools)."""
        self.one_zenoh_thread = one_zenoh_thread
        self.service = service
        self.announce = announce
        self.retry = retry
        self.config = config
        self.robot = config.name
        self.mode = mode
        self.log = logging.getLogger(f"icefloe.{service}")
        self.limited = LimitedLog(self.log)
        """For lines about bad input: a few per second per kind (see `icefloe.logs`)."""
        self.session: zenoh.Session
        self._closables: list[Any] = []
        self._readers: list[threading.Thread] = []
        """`deliver_on_thread` threads of queryables and `on_samples`, joined when the session closes."""
        self._log_handler: _BusLogHandler | None = None
        self._tasks: set[asyncio.Task[Any]] = set()
        self._seq = 0
        # Stamps from a clock that never jumps back: the wall clock read once, then advanced by
        # the monotonic clock (hwbridge learns its offset from the robot's clock).
        self._wall0, self._mono0 = time.time_ns(), time.monotonic_ns()
        self._numbering = threading.Lock()

    def key(self, topic: Topic | str) -> str:
        return keys.key(self.robot, topic)

    def short(self, key_expr: str) -> str:
        """A key without ``icefloe/<this robot>/`` (for counts of log lines: `LimitedLog` kinds)."""
        return key_expr.removeprefix(keys.key(self.robot, ""))

    def own_key(self, key_expr: str, arrived: str) -> bool:
        """Did a message for ``key_expr`` come on one concrete key (``arrived``), as every real
        sender puts it? A put or query on a wildcard (``icefloe/*/cmd/twist`` reaches the
        subscriber of ``icefloe/sim/cmd/twist`` too, and arrives as such) is not taken: False,
        and one rate-limited warning naming it. Typed subscriptions and command queryables use
        this; so does any raw subscriber that takes commands (hwbridge's ``cmd/stop``)."""
        if keys.is_concrete(arrived):
            return True
        self.limited.warning(f"{self.short(key_expr)} wildcard",
                             "dropped a message sent to %s (for %s): a wildcard, not a key; "
                             "messages are taken on their own key only", arrived, key_expr)
        return False

    def command(self, kind: type[C], **fields: Any) -> C:
        """A command of type ``kind`` (`Twist`, `WheelSpeeds`, `Stop`, `Motion`, `Halt`) with
        ``fields``, numbered and stamped as this session's next one: ``sender`` its Zenoh id,
        ``seq`` one more than the last, ``stamp`` now. With these hwbridge puts a stop and the
        motion commands around it in the order they were issued, whatever priority each took
        (docs/hwbridge.md, "Which command wins"). Any thread may call it."""
        with self._numbering:
            self._seq += 1
            seq, stamp = self._seq, self._wall0 + time.monotonic_ns() - self._mono0
        return kind(sender=str(self.session.zid()), seq=seq, stamp=stamp, **fields)

    async def __aenter__(self) -> Node:
        with service_zenoh_pools() if self.one_zenoh_thread else contextlib.nullcontext():
            self.session = await open_session(self.config, mode=self.mode, log=self.log, retry=self.retry)
        if self.announce:
            token = self.session.liveliness().declare_token(keys.alive_key(self.robot, self.service))
            self._closables.append(token)
        self._log_handler = _BusLogHandler(self)
        self.log.addHandler(self._log_handler)
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        self.close()

    def close(self) -> None:
        """Undeclare everything and close the session (idempotent)."""
        if self._log_handler is not None:
            self.log.removeHandler(self._log_handler)
            self._log_handler = None
        for task in self._tasks:
            task.cancel()
        closables, self._closables = self._closables, []
        for item in reversed(closables):
            with contextlib.suppress(Exception):
                if isinstance(item, Subscription):
                    item.close()
                else:
                    item.undeclare()
        if hasattr(self, "session") and not self.session.is_closed():
            self.session.close()
        for reader in self._readers:
            join_reader(reader, self.log)
        self._readers.clear()

    # ------------------------------------------------------------------ subscribing

    def subscribe(self, topic: Topic, *, latest: bool | None = None, maxsize: int = 64,
                  robot: str | None = None) -> Subscription[Any]:
        """Typed messages of ``topic``. Default policy: fifo for commands, latest for state."""
        if latest is None:
            latest = topic.kind == "out"
        sub: Subscription[Any] = Subscription(self, keys.key(robot or self.robot, topic), topic.type,
                                              latest=latest, maxsize=maxsize)
        self._closables.append(sub)
        return sub

    def batches(self, topic: Topic, period: float, *, maxsize: int = 4096,
                robot: str | None = None) -> Batches[Any]:
        """Typed messages of ``topic`` as one list every ``period`` s (see `Batches`)."""
        sub: Batches[Any] = Batches(self, keys.key(robot or self.robot, topic), _decoder(topic),
                                    period=period, maxsize=maxsize)
        self._closables.append(sub)
        return sub

    def latest(self, topic: Topic, *, robot: str | None = None) -> Latest[Any]:
        """The newest message of ``topic``, read when you ask (see `Latest`)."""
        latest: Latest[Any] = Latest(self, keys.key(robot or self.robot, topic), _decoder(topic))
        self._closables.append(latest)
        return latest

    def subscribe_raw(self, key_expr: str, *, maxsize: int = 1024) -> Subscription[Any]:
        """Undecoded samples of any key expression (wildcards allowed), in order."""
        sub: Subscription[Any] = Subscription(self, key_expr, None, latest=False, maxsize=maxsize)
        self._closables.append(sub)
        return sub

    # ------------------------------------------------------------------ publishing

    def publisher(self, topic: Topic, *, express: bool = False, robot: str | None = None) -> Publisher[Any]:
        """Publishes ``topic`` on this robot, or on ``robot`` (the lab's localizer speaks for every robot)."""
        pub: Publisher[Any] = Publisher(self, topic, express=express, robot=robot)
        self._closables.append(pub._pub)
        return pub

    # ------------------------------------------------------------------ queries

    def queryable(self, topic: Topic, handler: Callable[[Any], Awaitable[Message]]) -> None:
        """Answer queries on ``topic`` with ``await handler(request)``; bad requests get an error reply.

        At most `MAX_QUERIES` are answered at once; more get a "busy" error reply at once, so a
        flood of queries costs neither memory nor the event loop's time."""
        loop = asyncio.get_running_loop()
        key_expr = self.key(topic)
        slots = threading.BoundedSemaphore(MAX_QUERIES)

        async def answer(query: zenoh.Query) -> None:
            if topic.command and not self.own_key(key_expr, str(query.key_expr)):
                query.drop()  # no answer: a command is taken on its own key only
                return
            try:
                request = decode_query(query, topic.type, key_expr)
                reply = await handler(request)
                query.reply(key_expr, codec.encode(reply), encoding=MSGPACK)
            except BadPayload as exc:
                self.limited.warning(topic.name, "rejected query: %s", exc)
                query.reply_err(printable(str(exc)))
            except Exception as exc:
                self.limited.error(f"{topic.name} failed", "query %s failed", key_expr, exc_info=exc)
                query.reply_err(printable(f"{key_expr}: {type(exc).__name__}: {exc}"))
            finally:
                query.drop()
                slots.release()

        def on_query(query: zenoh.Query) -> None:  # our reader thread: never block
            if not slots.acquire(blocking=False):
                self.limited.warning(f"{topic.name} busy", "refused a query on %s: %d already being answered",
                                     key_expr, MAX_QUERIES)
                query.reply_err(f"{key_expr}: busy ({MAX_QUERIES} queries being answered); ask again later")
                query.drop()
                return
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(self._spawn, answer(query))

        queryable = self.session.declare_queryable(key_expr, zenoh.handlers.DefaultHandler())
        self._closables.append(queryable)
        self._readers.append(deliver_on_thread(queryable.handler, on_query, f"icefloe {key_expr}", self.limited))

    def on_samples(self, key_expr: str, callback: Callable[[zenoh.Sample], object],
                   **options: Any) -> Any:
        """Call ``callback`` with each raw sample on ``key_expr``, on a reader thread of this node
        (`deliver_on_thread`; never block in it); ``options`` go to ``declare_subscriber``
        (``allowed_origin=zenoh.Locality.REMOTE``). Returns the subscriber; undeclare it, or let
        `close` do it."""
        subscriber = self.session.declare_subscriber(key_expr, zenoh.handlers.DefaultHandler(), **options)
        self._closables.append(subscriber)
        self._readers.append(deliver_on_thread(subscriber.handler, callback, f"icefloe {key_expr}", self.limited))
        return subscriber

    def _spawn(self, coro: Awaitable[Any]) -> None:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def query(self, topic: Topic, request: Message | None = None, *, timeout: float = 2.0,
                    robot: str | None = None) -> Any:
        """Ask a queryable and return its typed answer; `NotReachable` if nobody answers."""
        key_expr = keys.key(robot or self.robot, topic)
        payload = codec.encode(request) if request is not None else None

        def ask() -> Any:
            start = time.monotonic()
            replies = self.session.get(key_expr, payload=payload, encoding=MSGPACK if payload else None,
                                       timeout=timeout)
            for reply in replies:
                if reply.ok is not None:
                    s = reply.ok
                    return codec.decode(s.payload.to_bytes(), str(s.encoding), topic.reply, key_expr)
                raise BadPayload(f"{key_expr}: {reply.err.payload.to_string()}")
            if time.monotonic() - start < timeout / 2:  # Zenoh ends a query at once when nobody serves it
                raise NotReachable(f"{key_expr}: nobody answers (is its service running, and may you call it?)")
            raise NotReachable(f"{key_expr}: no answer within {timeout} s")

        return await asyncio.to_thread(ask)

    async def alive(self, robot: str | None = None) -> list[str]:
        """Services holding a liveliness token on a robot (``*`` for every robot): the tokens
        ``icefloe/<robot>/alive/<service>``; a wildcard token (``icefloe/*/alive/x``) is no service."""
        robot = robot or self.robot
        pattern = keys.alive_key(robot, "*")
        replies = await asyncio.to_thread(lambda: list(self.session.liveliness().get(pattern, timeout=1.0)))
        tokens = {str(r.ok.key_expr) for r in replies if r.ok is not None}
        return sorted(t for t in tokens if (who := keys.alive_of(t)) and robot in ("*", who[0]))


class _BusLogHandler(logging.Handler):
    """Copies a service's log records to the bus key ``log``.

    At most `BUS_LOG_RATE` lines a second (`BUS_LOG_BURST` at once) go to the bus, so a service
    in trouble cannot flood it; its own output (stderr) keeps every line. The next line copied
    says how many were left out."""

    LEVELS: ClassVar[dict[int, str]] = {10: "debug", 20: "info", 30: "warning", 40: "error", 50: "critical"}

    def __init__(self, node: Node, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(logging.INFO)
        self._service = node.service
        self._pub = node.session.declare_publisher(node.key(keys.LOG), encoding=MSGPACK)
        node._closables.append(self._pub)
        self._clock = clock
        self._tokens, self._refilled = float(BUS_LOG_BURST), clock()
        self.left_out = 0
        """Lines not copied since the last one that was."""

    def emit(self, record: logging.LogRecord) -> None:  # under the handler's lock
        try:
            now = self._clock()
            self._tokens = min(BUS_LOG_BURST, self._tokens + (now - self._refilled) * BUS_LOG_RATE)
            self._refilled = now
            if self._tokens < 1.0:
                self.left_out += 1
                return
            self._tokens -= 1.0
            text = printable(record.getMessage(), 1000)
            if self.left_out:
                text += f" [{self.left_out} lines before this one not copied to the bus]"
                self.left_out = 0
            level = self.LEVELS.get(record.levelno - record.levelno % 10, "info")
            msg = Log(stamp=time.time_ns(), level=level, service=self._service, text=text)
            self._pub.put(codec.encode(msg))
        except Exception:  # a log line must never take a service down
            pass


SERVICE_ZENOH_RUNTIME = ("(app: (worker_threads: 1), acc: (handover: app), net: (handover: app), "
                         "rx: (handover: app), tx: (handover: app))")
"""Zenoh's thread pools for a service: one worker thread instead of pools sized for a server.
Fewer thread hand-offs per sample: on the 2-core test machine the session of a 1 kHz subscriber
costs half the CPU, at the same latency (docs/runtime.md). The router and the simulator keep
Zenoh's defaults (``Node(one_zenoh_thread=False)``). A ``ZENOH_RUNTIME`` set in the environment
wins."""


@contextlib.contextmanager
def service_zenoh_pools() -> Iterator[None]:
    """`SERVICE_ZENOH_RUNTIME` while the process's first session opens (Zenoh reads it then, once),
    unless ``ZENOH_RUNTIME`` is already set; removed after, so child processes do not inherit it."""
    if "ZENOH_RUNTIME" in os.environ:
        yield
        return
    os.environ["ZENOH_RUNTIME"] = SERVICE_ZENOH_RUNTIME
    try:
        yield
    finally:
        del os.environ["ZENOH_RUNTIME"]


def raw_session(config: RobotConfig) -> zenoh.Session:
    """A plain zenoh-python session to the robot's router, with a service's thread pools: for the
    benchmarks' raw-Zenoh references, so they compare like for like."""
    with service_zenoh_pools():
        return zenoh.open(zenoh_config(config, connect=config.zenoh.connect))


def listening(endpoint: str, timeout: float = 1.0) -> bool:
    """Does anything accept a TCP connection at a Zenoh endpoint (``tcp/host:port``, ``tls/...``)?
    True for other kinds of endpoints, which we cannot probe."""
    import socket

    proto, _, address = endpoint.partition("/")
    if proto not in ("tcp", "tls"):
        return True
    host, _, port = address.split("#", 1)[0].rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout):
            return True
    except (OSError, ValueError):
        return False


def why_unreachable(config: RobotConfig, endpoints: Sequence[str]) -> str:
    """One line saying why a session could not open, and what to do (Zenoh only says
    "Unable to connect", with a path in its Rust source, whatever the reason)."""
    if not any(listening(e) for e in endpoints):
        return ("nothing listens there. Is the robot up? `./deploy/up.sh` runs the simulated one; for a "
                "real robot give its address (--connect tcp/<robot-ip>:7447, or Robot(connect=...))")
    if config.zenoh.user:
        return (f"the router refused user {config.zenoh.user!r}: wrong credentials? (ask the robot's owner "
                "for its credentials file, made by `icefloe credentials --sheet`, and give --credentials FILE)")
    return ("the router refused the session: it wants a user and password "
            "(give --credentials FILE, the robot's credentials file), or it is not a Zenoh router")


async def open_session(config: RobotConfig, *, mode: str = "client", log: logging.Logger | None = None,
                       retry: bool = True) -> zenoh.Session:
    """Open a Zenoh session to the robot's router, retrying while it is not up yet."""
    log = log or logging.getLogger("icefloe")
    endpoints = list(config.zenoh.connect)
    delay = 0.1
    while True:
        try:
            zc = zenoh_config(config, mode=mode, connect=endpoints)
            return await asyncio.to_thread(zenoh.open, zc)
        except zenoh.ZError:
            if not config.zenoh.user and not config.zenoh.access_control:
                # Perhaps the robot requires credentials: try the read-only guest once.
                with contextlib.suppress(zenoh.ZError):
                    session = await asyncio.to_thread(
                        zenoh.open, zenoh_config(config, mode=mode, connect=endpoints, guest=True))
                    log.warning("connected as the read-only user %r: this session cannot command the robot",
                                GUEST_USER)
                    return session
            if not retry:
                raise NotReachable(f"cannot reach a Zenoh router at {', '.join(endpoints)}: "
                                   f"{why_unreachable(config, endpoints)}") from None
            if delay >= 1.0:
                log.warning("cannot reach a Zenoh router at %s yet; retrying", ", ".join(endpoints))
            await asyncio.sleep(delay)
            delay = min(delay * 2, 5.0)


# ---------------------------------------------------------------------- __main__ of a service


def arguments(description: str, argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=description)
    # `icefloe up` tells your own programs their robot's config in ICEFLOE_CONFIG (launcher.py).
    parser.add_argument("--config", default=os.environ.get("ICEFLOE_CONFIG") or None,
                        help="robot config: a name (sim, penguin1) or a path to a .toml file "
                             "(default: $ICEFLOE_CONFIG, else sim)")
    parser.add_argument("--connect", action="append", help="Zenoh endpoint of the robot, e.g. tcp/10.0.0.5:7447")
    parser.add_argument("--log-level", default="INFO")
    return parser.parse_args(argv)


def load_config(args: argparse.Namespace) -> RobotConfig:
    """The robot config named by ``--config``, with ``--connect`` applied."""
    cfg = config_mod.load(args.config)
    if args.connect:
        cfg = msgspec.structs.replace(cfg, zenoh=msgspec.structs.replace(cfg.zenoh, connect=args.connect))
    return cfg


CANNOT_START = 2
"""Exit status of a service that cannot start (a missing device, a port in use): it says why in
one line, and restarting it will not help. (A config it refuses: `EXIT_CONFIG`.)"""


def run_async(coro: Coroutine[Any, Any, T2]) -> T2:
    """``asyncio.run``, on uvloop where it is installed: it halves the hop from Zenoh's
    threads into the loop (bench/runtime_latency.py measures it)."""
    try:
        import uvloop
    except ImportError:
        return asyncio.run(coro)
    return uvloop.run(coro)


def process_name() -> str:
    """``icefloe <service>`` for ``python -m icefloe.services.<service>`` (or the router), else ``icefloe``."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    module = spec.name.removesuffix(".__main__") if spec else ""
    if module.startswith("icefloe.services.") or module == "icefloe.router":
        return f"icefloe {module.rsplit('.', 1)[-1]}"
    return "icefloe"


def run(main: Callable[[RobotConfig], Awaitable[int | None]], argv: Sequence[str] | None = None,
        description: str | None = None) -> None:
    """Run a service's ``main(config)`` until it returns or SIGINT/SIGTERM arrives.

    A non-zero int returned by ``main`` becomes the process's exit status (a signal exits 0).
    A `ConfigError` (reading the config, or raised by ``main``) is one line on stderr and the
    exit status `EXIT_CONFIG` (78), which `icefloe up` does not restart: it stops the robot. Any
    other `IcefloeError` (a missing device, a port in use, named in its message) is one line and
    `CANNOT_START` (2): that service is not restarted either.
    """
    args = arguments(description or main.__module__, argv)
    logging.basicConfig(stream=sys.stderr, level=args.log_level.upper(),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        cfg = load_config(args)
        config_mod.private_dir(cfg.runtime_dir)  # sockets, ptys, the router's password file: ours only
    except ConfigError as exc:
        print(f"icefloe: {exc}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG) from None

    async def supervised() -> int | None:
        loop = asyncio.get_running_loop()
        task = asyncio.current_task()
        assert task is not None
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, task.cancel)
        try:
            return await main(cfg)
        except asyncio.CancelledError:
            return 0
        except ConfigError as exc:  # the config does not fit (the board, a world file): stop the robot
            print(f"{service}: {exc}", file=sys.stderr, flush=True)
            return EXIT_CONFIG
        except IcefloeError as exc:  # could not start or go on: one line that says why, no traceback
            print(f"{service}: {exc}", file=sys.stderr, flush=True)
            return CANNOT_START

    service = process_name()
    status = run_async(supervised())
    if status:
        raise SystemExit(status)
