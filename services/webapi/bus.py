"""The bus over HTTP, in the shape of Zenoh's REST plugin (docs/webapi.md, "The bus over HTTP").

For languages and places with no Zenoh binding (a browser, MATLAB Online, R, a spreadsheet,
a shell script with curl)::

    GET  /bus/<key>        the latest sample of a topic, or a query's answers (queryables)
    POST /bus/<key>        a query whose request is the JSON body (a browser cannot send a GET body)
    PUT  /bus/<key>        publish the JSON body, checked against the key's message first
    GET  /bus/<key-expr>   with ``Accept: text/event-stream``: every sample, as Server-Sent Events

``<key>`` is a name of the key table on this robot (``odom/pose``, ``alive/hwbridge``) or a
full key (``icefloe/penguin1/odom/pose``); a key expression may hold wildcards (``*``, ``**``).
Answers are Zenoh's REST shape, a JSON array of ``{"key", "value", "encoding", "time"}``
(the value is the message as JSON, bytes as base64); ``?_raw`` gives the value alone. A
stream's events are ``PUT`` (``DELETE`` when a liveliness token goes) with one such object
each; ``?_rate=HZ`` sends at most HZ samples a second of each key, the newest.

Keys outside the key table are 404; a body that is not the key's message is 400 naming
the field; queries a service refuses are 502 with its reason; no answer is 503.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import msgspec
import zenoh
from aiohttp import web

from icefloe.errors import BadPayload
from icefloe.logs import LimitedLog
from icefloe.runtime import JSON, MSGPACK
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m
from icefloe.schemas.keys import Topic

from .fanout import Busy, Hub, Raw, Reader, Rendered, stamp_text

log = logging.getLogger("icefloe.webapi")

STREAM_STALL_S = 10.0
"""A stream whose client has not taken a write for this long is closed (as Zenoh's REST plugin does)."""
KEEPALIVE_S = 15.0
"""An idle stream sends a comment this often, so a client that left is noticed."""
MAX_STREAMS = 200
"""Streams open at once; more are refused (503)."""
MAX_QUERIES = 32
"""Queries under way at once; more are refused (503)."""
MAX_BODY = 1 << 20
"""Largest request body, bytes."""
LATEST_WAIT_S = 2.0
"""GET of a topic nobody has published on yet waits this long for a sample, s."""
MAX_QUERY_S = 60.0
"""Longest a query may wait for its answers, s (``_timeout``)."""
ALIVE = "alive"


class Sample(msgspec.Struct):
    """One sample as JSON, as Zenoh's REST plugin shows it."""

    key: str
    value: Any
    encoding: str
    time: str


_encode = msgspec.json.Encoder().encode


class HttpError(Exception):
    """A refusal: HTTP ``status`` with ``{"message": ...}``."""

    def __init__(self, status: int, message: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(message)
        self.status, self.message, self.headers = status, message, headers or {}


def error(status: int, message: str, headers: dict[str, str] | None = None) -> web.Response:
    return web.Response(status=status, body=json.dumps({"message": message}).encode(),
                        content_type="application/json", headers=headers)


def value_of(key: str, payload: bytes, encoding: str) -> Any:
    """The message of a sample (typed by the key table, else plain data); `BadPayload` if it is not."""
    topic = keys.topic_of(key)
    if topic is not None and topic.kind != "query":
        return codec.decode(payload, encoding, topic.type, key)
    if not payload:
        return None
    try:
        return codec.to_builtins(payload, encoding)
    except (msgspec.DecodeError, BadPayload) as exc:
        raise BadPayload(f"{key}: {exc}") from None


_warn = LimitedLog(log)


def render(raw: Raw) -> Rendered | None:
    """A sample as the JSON object HTTP clients get; None (and one limited line) if it does not decode."""
    try:
        value = None if raw.kind == "DELETE" else value_of(raw.key, raw.payload, raw.encoding)
    except BadPayload as exc:
        _warn.warning("HTTP bridge sample", "HTTP bridge: dropped a sample: %s", exc)
        return None
    return Rendered(raw.key, raw.kind, _encode(Sample(raw.key, value, "application/json", raw.time)))


def sse(sample: Rendered) -> bytes:
    """One Server-Sent Event: ``event: PUT`` and the sample's JSON as its data."""
    return b"event: " + sample.kind.encode() + b"\ndata: " + sample.json + b"\n\n"


# ---------------------------------------------------------------------- keys


@dataclass(frozen=True)
class Target:
    """What a request's path names on the bus."""

    key_expr: str
    concrete: bool
    """One key, no wildcard."""
    topic: Topic | None
    """The key-table row of a concrete key (None for a liveliness token or a wildcard)."""
    samples: bool
    """It reaches keys of the key table (topics or queryables)."""
    alive: bool
    """It reaches liveliness tokens (``alive/<service>``)."""


_TABLE_EXPRS = [(zenoh.KeyExpr(keys.key("*", t.name)), t) for t in keys.TABLE.values()]
_ALIVE_EXPR = zenoh.KeyExpr(keys.alive_key("*", "*"))


def concrete(key_expr: str) -> bool:
    """One key, no ``*``, ``**`` or ``$*``."""
    return "*" not in key_expr


def target(path: str, robot: str) -> Target:
    """The key expression of ``/bus/<path>``; `HttpError` 400 if it is not one, 404 if it reaches
    no key of the key table (nor a liveliness token)."""
    path = path.strip("/")
    full = path if path == keys.PREFIX or path.startswith(keys.PREFIX + "/") else keys.key(robot, path)
    try:
        expr = zenoh.KeyExpr.autocanonize(full)
    except Exception:  # zenoh raises ZError for anything that is not a key expression
        raise HttpError(400, f"{full!r} is not a key expression") from None
    key_expr = str(expr)
    one = concrete(key_expr)
    topic = keys.topic_of(key_expr) if one else None
    samples = topic is not None if one else any(e.intersects(expr) for e, _ in _TABLE_EXPRS)
    alive = _ALIVE_EXPR.intersects(expr)
    if not (samples or alive):
        what = "not a key" if one else "reaches no key"
        raise HttpError(404, f"{key_expr}: {what} of the key table (schemas/keys.py)")
    return Target(key_expr, one, topic, samples, alive)


def queryables(expr: str) -> list[Topic]:
    """The key-table queryables a key expression reaches."""
    ke = zenoh.KeyExpr(expr)
    return [t for e, t in _TABLE_EXPRS if t.kind == "query" and e.intersects(ke)]


# ---------------------------------------------------------------------- the bridge


@dataclass
class Caller:
    """Who a request comes from, and the session that acts for them (so the router checks them too)."""

    user: str
    """The Zenoh user ("" on a robot without access control)."""
    session: zenoh.Session
    hub: Hub
    challenge: dict[str, str] | None = None
    """Set when the request gave no login: a refusal is then 401 with this challenge (the owner
    may log in), not 403."""


Order = Callable[[m.Message], m.Message]


class Bridge:
    """The ``/bus/...`` routes. ``caller`` picks who a request is from (`Caller`), ``allowed``
    says whether they may do a Zenoh operation (``put``, ``query``, ``declare_subscriber``,
    ``liveliness_query``, ...) on a key expression, and ``order`` numbers a command the client
    did not number itself (see `icefloe.client.AsyncRobot.command`)."""

    def __init__(self, robot: str, caller: Callable[[web.Request], Caller],
                 allowed: Callable[[Caller, str, str], bool] | None = None,
                 order: Order | None = None, *, query_timeout: float = 2.0) -> None:
        self.robot = robot
        self.caller = caller
        self.allowed = allowed or (lambda caller, message, key_expr: True)
        self.order = order or (lambda message: message)
        self.query_timeout = query_timeout
        self.streams = 0
        self._queries = asyncio.Semaphore(MAX_QUERIES)
        self._publishers: dict[tuple[int, str], zenoh.Publisher] = {}
        self._tasks: set[asyncio.Task[Any]] = set()

    def routes(self, app: web.Application) -> None:
        app.router.add_route("*", "/bus/{path:.*}", self.handle)

    async def handle(self, request: web.Request) -> web.StreamResponse:
        try:
            if request.method == "OPTIONS":
                return self.preflight(request)
            where = target(request.match_info["path"], self.robot)
            who = self.caller(request)
            if request.method in ("GET", "HEAD"):
                if "text/event-stream" in request.headers.get("Accept", ""):
                    return await self.stream(request, who, where)
                return await self.get(request, who, where)
            if request.method == "POST":
                return await self.get(request, who, where)
            if request.method == "PUT":
                return await self.put(request, who, where)
            raise HttpError(405, f"{request.method} is not a bus operation: GET, POST or PUT",
                            {"Allow": "GET, POST, PUT"})
        except HttpError as exc:
            return self.cors(error(exc.status, exc.message, exc.headers), request)

    # ------------------------------------------------------------------ access

    def check(self, who: Caller, message: str, key_expr: str) -> None:
        """403 unless ``who`` may send a ``message`` on ``key_expr`` (the router's own decision)."""
        if not self.allowed(who, message, key_expr):
            if who.challenge is not None:
                raise HttpError(401, f"{key_expr}: to {message.replace('_', ' ')} here, log in as the robot's "
                                     "owner (HTTP Basic)", who.challenge)
            whom = f"user {who.user!r}" if who.user else "you"
            raise HttpError(403, f"{key_expr}: {whom} may not {message.replace('_', ' ')} here "
                                 "(only the robot's owner commands it)")

    def cors(self, response: web.StreamResponse, request: web.Request) -> web.StreamResponse:
        """Any page may read the bus, as Zenoh's REST plugin allows (`Access-Control-Allow-Origin: *`)."""
        response.headers["Access-Control-Allow-Origin"] = "*"
        return response

    def preflight(self, request: web.Request) -> web.Response:
        return self.cors(web.Response(status=204, headers={
            "Access-Control-Allow-Methods": "GET, POST, PUT",
            "Access-Control-Allow-Headers": "Content-Type, Accept, Authorization",
            "Access-Control-Max-Age": "600"}), request)

    # ------------------------------------------------------------------ reading

    async def get(self, request: web.Request, who: Caller, where: Target) -> web.StreamResponse:
        raw = "_raw" in request.query
        if where.alive and not where.samples:
            self.check(who, "liveliness_query", where.key_expr)
            samples = await self.tokens(who, where.key_expr)
        elif where.topic is not None and where.topic.kind != "query":
            if request.method == "POST":
                raise HttpError(405, f"{where.key_expr} is a topic: GET its latest sample, PUT to publish",
                                {"Allow": "GET, PUT"})
            self.check(who, "declare_subscriber", where.key_expr)
            samples = [await self.latest(who, where.key_expr)]
        else:
            samples = await self.query(request, who, where)
        if raw:
            if not samples:
                raise HttpError(503, f"{where.key_expr}: nothing to show")
            return self.cors(web.Response(body=_encode(msgspec.json.decode(samples[0].json)["value"]),
                                          content_type="application/json"), request)
        body = b"[" + b",".join(s.json for s in samples) + b"]"
        return self.cors(web.Response(body=body, content_type="application/json"), request)

    async def latest(self, who: Caller, key: str) -> Rendered:
        """The newest sample of ``key``: kept by its channel, which this GET opens if needed."""
        try:
            channel = who.hub.channel(key)
        except Busy as exc:
            raise HttpError(503, str(exc)) from None
        if key not in channel.latest:
            try:
                await asyncio.wait_for(channel.arrived.wait(), LATEST_WAIT_S)
            except TimeoutError:
                raise HttpError(503, f"{key}: nothing published within {LATEST_WAIT_S:g} s "
                                     "(is its service running?)") from None
        return channel.latest[key]

    async def tokens(self, who: Caller, key_expr: str) -> list[Rendered]:
        """The liveliness tokens alive under ``key_expr``: the services that are running."""
        def ask() -> list[Rendered]:
            replies = who.session.liveliness().get(key_expr, timeout=1.0)
            found = {str(r.ok.key_expr) for r in replies if r.ok is not None}
            return [Rendered(k, "PUT", _encode(Sample(k, None, "application/json", "None"))) for k in sorted(found)
                    if concrete(k)]

        return await asyncio.to_thread(ask)

    async def query(self, request: web.Request, who: Caller, where: Target) -> list[Rendered]:
        """Ask the queryables of ``where``: the request is the body (JSON) or the URL's parameters."""
        reached = [where.topic] if where.topic is not None else queryables(where.key_expr)
        if not reached:
            raise HttpError(400, f"{where.key_expr}: a key expression with wildcards GETs queryables; "
                                 "for topics, send Accept: text/event-stream to follow them")
        self.check(who, "query", where.key_expr)
        body = await self.body(request)
        params = {k: v for k, v in request.query.items() if not k.startswith("_")}
        if body and params:
            raise HttpError(400, "give the request as the JSON body or as URL parameters, not both")
        kind = reached[0].type
        if any(t.type is not kind for t in reached):
            kind = m.Stop if not (body or params) else None  # several kinds: only the empty request fits all
            if kind is None:
                raise HttpError(400, f"{where.key_expr} reaches queryables that take different requests: "
                                     "name one key")
        try:
            if body:
                request_msg = codec.decode(body, codec.JSON, kind, where.key_expr)
            else:
                request_msg = msgspec.convert(params, kind, strict=False)
        except BadPayload as exc:
            raise HttpError(400, str(exc)) from None
        except msgspec.ValidationError as exc:
            raise HttpError(400, f"{where.key_expr}: {exc}") from None
        request_msg = self.order(request_msg)
        timeout = self.timeout(request, request_msg)
        if self._queries.locked():
            raise HttpError(503, f"{MAX_QUERIES} queries are under way already: try again later")
        async with self._queries:
            replies = await asyncio.to_thread(self._ask, who.session, where.key_expr, request_msg, timeout)
        if not replies:
            raise HttpError(503, f"{where.key_expr}: nobody answers within {timeout:g} s "
                                 "(is its service running?)")
        if where.concrete and len(replies) == 1 and isinstance(replies[0], str):
            raise HttpError(502, f"{where.key_expr}: {replies[0]}")
        return [r if isinstance(r, Rendered) else Rendered("ERROR", "PUT", _encode(
            Sample("ERROR", r, "text/plain", "None"))) for r in replies]

    def timeout(self, request: web.Request, message: m.Message) -> float:
        text = request.query.get("_timeout")
        if text is not None:
            try:
                value = float(text)
            except ValueError:
                value = math.nan
            if not 0 < value <= MAX_QUERY_S:
                raise HttpError(400, f"_timeout={text!r}: give seconds, more than 0 and at most {MAX_QUERY_S:g}")
            return value
        if isinstance(message, m.Motion):  # it answers when the motion has ended
            return message.duration + message.accel + self.query_timeout
        return self.query_timeout

    @staticmethod
    def _ask(session: zenoh.Session, key_expr: str, request: m.Message, timeout: float) -> list[Rendered | str]:
        """The replies (rendered) or errors (their text) of a query; runs in a thread."""
        out: list[Rendered | str] = []
        for reply in session.get(key_expr, payload=codec.encode(request), encoding=MSGPACK, timeout=timeout):
            if reply.ok is None:
                out.append(reply.err.payload.to_string())
                continue
            s = reply.ok
            key = str(s.key_expr)
            topic = keys.topic_of(key)
            try:
                if topic is not None and topic.reply is not None:
                    value: Any = codec.decode(s.payload.to_bytes(), str(s.encoding), topic.reply, key)
                else:
                    value = value_of(key, s.payload.to_bytes(), str(s.encoding))
            except BadPayload as exc:
                out.append(f"a reply that does not decode: {exc}")
                continue
            out.append(Rendered(key, "PUT", _encode(Sample(key, value, "application/json", stamp_text(s.timestamp)))))
        return out

    async def stream(self, request: web.Request, who: Caller, where: Target) -> web.StreamResponse:
        """Server-Sent Events: every sample on the key expression (and liveliness tokens under it)."""
        rate = self.rate(request)
        if where.samples:
            self.check(who, "declare_subscriber", where.key_expr)
        if where.alive:
            self.check(who, "declare_liveliness_subscriber", where.key_expr)
        if self.streams >= MAX_STREAMS:
            raise HttpError(503, f"{MAX_STREAMS} streams are open already: try again later")
        try:
            channel = who.hub.channel(where.key_expr, samples=where.samples, liveliness=where.alive)
        except Busy as exc:
            raise HttpError(503, str(exc)) from None
        response = web.StreamResponse(headers={"Content-Type": "text/event-stream", "Cache-Control": "no-cache",
                                               "X-Accel-Buffering": "no"})
        self.cors(response, request)
        self.streams += 1
        reader = channel.reader(rate)
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        try:
            await response.prepare(request)
            await response.write(b": icefloe " + where.key_expr.encode() + b"\n\n")
            await self._send(response, reader)
        except (ConnectionResetError, asyncio.CancelledError):
            pass  # the client left, or the service is stopping
        finally:
            self.streams -= 1
            self._tasks.discard(task)
            channel.drop(reader)
        return response

    @staticmethod
    def rate(request: web.Request) -> float | None:
        text = request.query.get("_rate")
        if text is None:
            return None
        try:
            rate = float(text)
        except ValueError:
            rate = math.nan
        if not 0 < rate <= 1000:
            raise HttpError(400, f"_rate={text!r}: give samples per second per key, more than 0, at most 1000")
        return rate

    async def _send(self, response: web.StreamResponse, reader: Reader) -> None:
        """Write the reader's batches; close a client that takes no write for `STREAM_STALL_S`."""
        batches = aiter(reader)
        dropped = 0
        while True:
            try:
                batch = await asyncio.wait_for(anext(batches), KEEPALIVE_S)
            except TimeoutError:
                batch = []
            except StopAsyncIteration:
                return
            data = b"".join(sse(s) for s in batch) if batch else b": keep-alive\n\n"
            if reader.dropped != dropped:
                data += b"event: dropped\ndata: " + str(reader.dropped - dropped).encode() + b"\n\n"
                dropped = reader.dropped
            try:
                await asyncio.wait_for(response.write(data), STREAM_STALL_S)
            except TimeoutError:
                _warn.warning("HTTP bridge stall", "HTTP bridge: a stream's client took nothing for %g s; closed it",
                              STREAM_STALL_S)
                return

    # ------------------------------------------------------------------ writing

    async def body(self, request: web.Request) -> bytes:
        if request.content_length is not None and request.content_length > MAX_BODY:
            raise HttpError(413, f"the body is {request.content_length} bytes; at most {MAX_BODY}")
        data = await request.content.read(MAX_BODY + 1)
        if len(data) > MAX_BODY:
            raise HttpError(413, f"the body is more than {MAX_BODY} bytes")
        return data

    async def put(self, request: web.Request, who: Caller, where: Target) -> web.Response:
        """Publish the body on one key, once it has decoded as the key's message."""
        if not where.concrete:
            raise HttpError(400, f"{where.key_expr}: one publishes to one key, not a wildcard")
        if where.topic is None or where.topic.kind == "query":
            what = "a liveliness token" if where.topic is None else "a queryable: GET or POST asks it"
            raise HttpError(405, f"{where.key_expr} is {what}", {"Allow": "GET, POST"})
        self.check(who, "put", where.key_expr)
        body = await self.body(request)
        msgpack = request.content_type == codec.MSGPACK
        try:
            message = codec.decode(body, codec.MSGPACK if msgpack else codec.JSON, where.topic.type, where.key_expr)
        except BadPayload as exc:
            raise HttpError(400, str(exc)) from None
        message = self.order(message)
        stamp = who.session.new_timestamp()
        self.publisher(who, where.key_expr, where.topic).put(codec.encode(message), timestamp=stamp)
        body_out = _encode(Sample(where.key_expr, message, "application/json", stamp_text(stamp)))
        return self.cors(web.Response(body=body_out, content_type="application/json"), request)

    def publisher(self, who: Caller, key: str, topic: Topic) -> zenoh.Publisher:
        """A declared publisher per key (cheaper than a put per request, and `icefloe topics -v` sees it)."""
        slot = (id(who.session), key)
        pub = self._publishers.get(slot)
        if pub is None:
            if len(self._publishers) >= 256:  # keys of many robots: keep the newest only
                self._publishers.pop(next(iter(self._publishers))).undeclare()
            pub = self._publishers[slot] = who.session.declare_publisher(
                key, encoding=MSGPACK, congestion_control=zenoh.CongestionControl.DROP, express=topic.urgent,
                priority=zenoh.Priority.REAL_TIME if topic.urgent else zenoh.Priority.DEFAULT)
        return pub

    async def close(self) -> None:
        for task in list(self._tasks):
            task.cancel()
        for pub in self._publishers.values():
            pub.undeclare()
        self._publishers.clear()


__all__ = ["JSON", "Bridge", "Caller", "HttpError", "Sample", "render", "target"]
