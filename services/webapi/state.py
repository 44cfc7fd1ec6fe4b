"""The robot's state for the old API's routes, followed only while the routes read it.

A web API with no HTTP client should cost nothing: it keeps no standing subscription to
``hw/wheels`` (100 Hz), ``odom/pose``, ``hw/battery`` or ``io/dip``. A route that reads one
of them subscribes (the first read after a pause), waits for the first sample at most a
bounded time, and keeps the subscription for `IDLE_S` after its last read, so a client
polling in a loop is answered at once from the newest sample. The subscription is the
runtime's `Latest`: Zenoh keeps only the newest sample (no Python runs per sample); it is
decoded when read, once.

The topics are a fixed few: whatever a client asks, at most that many subscriptions.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from typing import Any

from icefloe.runtime import Latest, Node
from icefloe.schemas import keys

IDLE_S = 30.0
"""A topic no route has read for this long is no longer followed, s."""
POLL_S = 0.005
"""While waiting for a first sample, look this often, s."""

FOLLOWED = (keys.WHEELS, keys.ODOM_POSE, keys.HW_BATTERY, keys.DIP)
"""The topics the routes read, and so the most this module ever follows."""


class Followed:
    """One topic while followed: its newest sample, kept by Zenoh and decoded when read
    (`icefloe.runtime.Latest`), and when a route last read it."""

    def __init__(self, node: Node, topic: keys.Topic) -> None:
        self.topic = topic
        self.latest: Latest[Any] = node.latest(topic)
        self.used = self.made = time.monotonic()

    def newest(self) -> Any:
        """The newest sample that decoded (a bad one is dropped with a line; the last good stays)."""
        return self.latest.get()

    def close(self) -> None:
        with contextlib.suppress(Exception):  # the session may be closing
            self.latest.undeclare()


class State:
    """``await state.get(keys.WHEELS, wait=2.0)``: the newest ``hw/wheels``, or None if none came."""

    def __init__(self, node: Node, idle_s: float = IDLE_S) -> None:
        self.node = node
        self.idle_s = idle_s
        self.followed: dict[str, Followed] = {}
        """Topic name -> its subscription, while followed."""
        self._janitor: asyncio.Task[None] | None = None

    def follow(self, *topics: keys.Topic) -> None:
        """Subscribe to ``topics`` now if not yet (a route about to read them: the samples come
        while it does its other work)."""
        now = time.monotonic()
        for topic in topics:
            if topic not in FOLLOWED:
                raise ValueError(f"webapi does not follow {topic.name}")
            followed = self.followed.get(topic.name)
            if followed is None:
                followed = self.followed[topic.name] = Followed(self.node, topic)
            followed.used = now
        if self._janitor is None:
            self._janitor = asyncio.create_task(self._sweep())

    async def get(self, topic: keys.Topic, wait: float) -> Any:
        """The newest message of ``topic``; after a pause, the first to come within ``wait`` s of
        subscribing (else None: a key nothing sends costs each later read no wait)."""
        self.follow(topic)
        followed = self.followed[topic.name]
        deadline = followed.made + wait
        while (value := followed.newest()) is None and time.monotonic() < deadline:
            await asyncio.sleep(POLL_S)
        return value

    async def _sweep(self) -> None:
        while True:
            await asyncio.sleep(self.idle_s / 2)
            now = time.monotonic()
            for name, followed in list(self.followed.items()):
                if now - followed.used > self.idle_s:
                    followed.close()
                    del self.followed[name]

    def close(self) -> None:
        if self._janitor is not None:
            self._janitor.cancel()
        for followed in self.followed.values():
            followed.close()
        self.followed.clear()
