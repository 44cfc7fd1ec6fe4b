"""The camera routes of the web API: ``/camera/get``, ``/camera/frame``, ``/camera/info``.

``/camera/get`` is the old server's MJPEG stream, byte for byte (facts §5.2): one part per
frame, ``--frame\\r\\nContent-Type: image/jpeg\\r\\n\\r\\n<JPEG>\\r\\n``, in a body that ends when
the connection closes (no Content-Length, and no chunked encoding whatever HTTP version the
client speaks: course clients cut the JPEGs out of the raw bytes). The bytes are the old
server's, but each JPEG is sent with the next part's boundary and head right behind it, so a
client that cuts a JPEG when it sees the next ``--frame`` has it at once, not a frame later.
Each part is the newest
frame, at the camera's capture rate: the frames come from ``camera/frames``, which the camera
publishes only while something subscribes, and `Feed` subscribes only while an HTTP client
watches. With ``[webapi] camera_get = "frame"`` it answers one JPEG instead (clients written
against a course simulator); ``/camera/frame`` always does. Such clients ask again and again:
after a one-JPEG request the web API follows ``camera/frames`` for `LINGER_S` more, so the
next request is answered at once with the newest frame, without a query to the camera.

A slow client never slows the others or grows the service's memory: each watcher sends the
newest frame when its socket takes it (the frames it could not take are skipped, never
queued), and one that takes nothing for `STALL_S` is disconnected.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct
import threading
from collections.abc import Iterator

import msgspec
import zenoh
from aiohttp import web

from icefloe.errors import BadPayload, NotReachable
from icefloe.runtime import LoopWakeup, Node
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m

BOUNDARY = "frame"
HEAD = f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\n\r\n".encode()
"""Start of every part, as the old server wrote it."""
MAX_WATCHERS = 32
"""Clients watching ``/camera/get`` at once; one more is answered 503."""
STALL_S = 5.0
"""A watcher whose client takes no part for this long is disconnected, s."""
SEND_BUFFER = 128 * 1024
"""Kernel send buffer of a watcher's socket, bytes (Linux keeps twice this): some frames in flight."""
CHECK_S = 1.0
"""While no frame comes (no camera), a watcher looks this often whether its client left, s."""
FRESH_S = 0.5
"""A followed frame older than this is not answered (the camera may have stopped): ask it, s."""
LINGER_S = 5.0
"""After a one-JPEG request, ``camera/frames`` is followed this long for the next, s."""
FIRST_FRAME_S = 1.0
"""How long a new watcher's first part (a ``camera/frame`` query) may take, s."""


class ClosingStream(web.StreamResponse):
    """A body delimited by the connection's close: no Content-Length, no chunked encoding.

    aiohttp chunks a body of unknown length for HTTP/1.1 clients, unless the response turns
    its length bookkeeping off, as its own WebSocketResponse does (``_length_check``)."""

    _length_check = False

    def __init__(self, **kwargs: object) -> None:
        super().__init__(**kwargs)  # type: ignore[arg-type]
        self.force_close()  # "Connection: close": the end of the body is the end of the connection


class Feed:
    """``camera/frames`` while somebody watches: one Zenoh subscriber, however many watchers,
    declared with the first and undeclared with the last (the camera then stops sending)."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.key_expr = node.key(keys.FRAMES)
        self.watchers = 0
        self.part: bytes | None = None
        """The newest frame ready to send: its JPEG, CRLF, and the next part's head (`tail`)."""
        self.image: m.Image | None = None
        """The newest frame as it came."""
        self.arrived = 0.0
        """When it came (the loop's clock), s."""
        self.stamp = 0
        """Its capture stamp, ns."""
        self.seq = 0
        """Frames received since the service started (a watcher's "newer than")."""
        self._changed = asyncio.Event()
        self._loop = asyncio.get_running_loop()
        self._subscriber: zenoh.Subscriber | None = None
        self._lock = threading.Lock()
        self._pending: tuple[bytes, str] | None = None
        self._wakeup = LoopWakeup(self._loop, self._take)
        self._closed = False
        self._linger: asyncio.TimerHandle | None = None
        self._linger_until = 0.0

    @contextlib.contextmanager
    def watch(self) -> Iterator[None]:
        self._acquire()
        try:
            yield
        finally:
            self._release()

    def keep(self, seconds: float) -> None:
        """Follow the frames for ``seconds`` more (after a one-JPEG request: the next one comes soon)."""
        self._linger_until = self._loop.time() + seconds
        if self._linger is None:
            self._acquire()
            self._linger = self._loop.call_later(seconds, self._lingered)

    def _lingered(self) -> None:
        left = self._linger_until - self._loop.time()
        if left > 0:
            self._linger = self._loop.call_later(left, self._lingered)
            return
        self._linger = None
        self._release()

    def _acquire(self) -> None:
        self.watchers += 1
        if self._subscriber is None:
            self._subscriber = self.node.session.declare_subscriber(self.key_expr, self._on_sample)

    def _release(self) -> None:
        self.watchers -= 1
        if self.watchers == 0:
            self._unfollow()

    def fresh(self, within: float) -> m.Image | None:
        """The newest frame if it came in the last ``within`` s (the camera still sends), else None."""
        if self.image is not None and self._loop.time() - self.arrived <= within:
            return self.image
        return None

    def _unfollow(self) -> None:
        """Nobody watches: undeclare the subscriber (the camera stops sending) and hold no frame."""
        subscriber, self._subscriber = self._subscriber, None
        if subscriber is not None:
            with contextlib.suppress(Exception):  # the session is closing
                subscriber.undeclare()
        self.part = self.image = None

    def close(self) -> None:
        if self._linger is not None:
            self._linger.cancel()
            self._linger = None
            self.watchers -= 1
        self._unfollow()
        with self._lock:  # a Zenoh thread may still be delivering a frame: it finds no wake-up to signal
            self._closed = True
            self._wakeup.close()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        # Zenoh's thread: keep only the newest payload and wake the loop (once for all the frames
        # that come before it looks: `LoopWakeup`). Never block.
        with self._lock:
            if self._closed:
                return
            self._pending = (sample.payload.to_bytes(), str(sample.encoding))
            self._wakeup.signal()

    def _take(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, None
        if pending is None or self._subscriber is None:
            return
        try:
            image = codec.decode(pending[0], pending[1], m.Image, self.key_expr)
        except BadPayload as exc:
            self.node.limited.warning("bad frame", "%s", exc)
            return
        self.show(image)

    def show(self, image: m.Image) -> None:
        """Make ``image`` the newest frame and wake the watchers."""
        self.part, self.image, self.stamp = tail(image.data), image, image.stamp
        self.arrived = self._loop.time()
        self.seq += 1
        changed, self._changed = self._changed, asyncio.Event()
        changed.set()

    async def newer(self, seq: int, timeout: float) -> bool:
        """Wait until there is a frame newer than ``seq``; False after ``timeout`` s without one."""
        if self.seq > seq and self.part is not None:
            return True
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._changed.wait(), timeout)
        return self.seq > seq and self.part is not None


def tail(jpeg: bytes) -> bytes:
    """A JPEG as the stream sends it: the part's end, then the next part's boundary and head."""
    return jpeg + b"\r\n" + HEAD


def leaving(request: web.Request) -> bool:
    """Has the client closed its connection? (aiohttp does not cancel a handler for that.)"""
    return request.transport is None or request.transport.is_closing()


class Camera:
    """The camera routes; ``single``: ``/camera/get`` answers one JPEG (``[webapi] camera_get``)."""

    def __init__(self, node: Node, timeout: float, single: bool) -> None:
        self.node = node
        self.timeout = timeout
        self.single = single
        self.feed = Feed(node)
        self.streams: set[asyncio.Task[object]] = set()

    async def get(self, request: web.Request) -> web.StreamResponse:
        return await (self.frame(request) if self.single else self.stream(request))

    async def frame(self, request: web.Request) -> web.Response:
        """One JPEG: the newest frame, its capture stamp in ``X-Frame-Stamp`` (ns). From the frames
        followed since an earlier request, or else a ``camera/frame`` query."""
        image = self.feed.fresh(FRESH_S)
        self.feed.keep(LINGER_S)
        if image is None:
            image = await self.node.query(keys.FRAME, timeout=self.timeout)
        return web.Response(body=image.data, content_type="image/jpeg",
                            headers={"Cache-Control": "no-store", "X-Frame-Stamp": str(image.stamp)})

    async def info(self, request: web.Request) -> web.Response:
        """The intrinsics of the frames these routes serve (``camera/info``), as JSON."""
        info: m.CameraInfo = await self.node.query(keys.CAMERA_INFO, timeout=self.timeout)
        return web.Response(body=msgspec.json.encode(info), content_type="application/json")

    async def stream(self, request: web.Request) -> web.StreamResponse:
        """The MJPEG stream, until the client leaves (or takes nothing for `STALL_S`)."""
        if request.method == "HEAD":  # the headers only: a HEAD must not hold a watcher
            return web.Response(headers={"Content-Type": f"multipart/x-mixed-replace; boundary={BOUNDARY}"})
        if self.feed.watchers >= MAX_WATCHERS:
            self.node.limited.warning("camera full", "/camera/get: %d clients watch already; refused %s",
                                      MAX_WATCHERS, request.remote)
            message = f"{MAX_WATCHERS} clients watch the camera already: try again later"
            return web.Response(status=503, body=msgspec.json.encode({"message": message}),
                                content_type="application/json")
        sock = request.transport.get_extra_info("socket") if request.transport is not None else None
        if sock is not None:  # a bounded kernel buffer too: a client that stops reading is seen soon
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER)
        response = ClosingStream(headers={"Content-Type": f"multipart/x-mixed-replace; boundary={BOUNDARY}"})
        await response.prepare(request)
        task = asyncio.current_task()
        assert task is not None
        self.streams.add(task)
        try:
            with self.feed.watch():
                await self._send(request, response)
        except (ConnectionError, asyncio.CancelledError):
            pass  # the client left, or the service is stopping
        finally:
            self.streams.discard(task)
        return response

    async def _send(self, request: web.Request, response: ClosingStream) -> None:
        seq, sent = self.feed.seq, -1
        await self._write(request, response, HEAD)
        if self.feed.fresh(FRESH_S) is not None:
            seq -= 1  # others watch: their newest frame first
        else:
            # The newest frame at once, so a viewer starts before the subscription has reached the camera.
            try:
                first: m.Image = await self.node.query(keys.FRAME, timeout=FIRST_FRAME_S)
            except (NotReachable, BadPayload):
                pass  # no camera (yet): wait for its frames below
            else:
                if self.feed.seq == seq:
                    sent = first.stamp
                    await self._write(request, response, tail(first.data))
        while not leaving(request):
            if not await self.feed.newer(seq, CHECK_S):
                continue  # no camera (yet): keep the stream open, as the old server did
            seq, part = self.feed.seq, self.feed.part
            assert part is not None
            if self.feed.stamp != sent:  # (the first frame again, when the query's came before it)
                await self._write(request, response, part)
            sent = -1

    async def _write(self, request: web.Request, response: ClosingStream, part: bytes) -> None:
        try:
            async with asyncio.timeout(STALL_S):
                await response.write(part)
        except TimeoutError:
            self.node.limited.warning("camera stalled", "/camera/get: %s took no frame for %.0f s: disconnected",
                                      request.remote, STALL_S)
            if request.transport is not None:
                sock = request.transport.get_extra_info("socket")
                with contextlib.suppress(OSError, AttributeError):  # close with a reset: the kernel
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # keeps nothing
                request.transport.abort()  # drop what waits for it: its memory goes with it
            raise ConnectionResetError("stalled client") from None

    def close(self) -> None:
        for task in list(self.streams):
            task.cancel()
        self.feed.close()
