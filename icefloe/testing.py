"""Helpers for testing your own services, as icefloe tests its own (docs/own-services.md).

    async with local_bus() as config:         # a Zenoh router in this process, on a free port
        task = asyncio.create_task(my_service.main(config))
        async with Node("tester", config) as node:
            ...                                # publish what it reads, check what it publishes

Two sessions in one process and a router between them: the real bus, with no `icefloe up`
and no robot. `icefloe new-service` writes a test that uses it.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import tempfile
from collections.abc import AsyncIterator, Awaitable, Callable

import msgspec
import zenoh

from . import config as config_mod
from .config import RobotConfig
from .runtime import zenoh_config


def free_port() -> int:
    """A TCP port nobody listens on now, on this machine."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.asynccontextmanager
async def local_bus(name: str = "test", config: RobotConfig | None = None) -> AsyncIterator[RobotConfig]:
    """A robot config (``config``, default: the simulated robot) named ``name`` whose bus is a
    Zenoh router in this process, listening on a free local port; closed on exit."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    base = config or config_mod.load()
    with tempfile.TemporaryDirectory(prefix="icefloe-test-") as run_dir:
        robot = msgspec.structs.replace(
            base, name=name, run_dir=run_dir,
            zenoh=msgspec.structs.replace(base.zenoh, listen=[endpoint], connect=[endpoint], access_control=False,
                                          credentials="", user="", password=""))
        router = await asyncio.to_thread(zenoh.open, zenoh_config(robot, mode="router", listen=[endpoint]))
        try:
            yield robot
        finally:
            router.close()


async def eventually(check: Callable[[], Awaitable[bool] | bool], timeout: float = 10.0,
                     interval: float = 0.05) -> None:
    """Wait until ``check()`` is true (it may be async); AssertionError after ``timeout`` s.
    For what arrives over the bus: messages take a moment, more on a busy machine."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        result = check()
        if asyncio.iscoroutine(result) or isinstance(result, Awaitable):
            result = await result
        if result:
            return
        if loop.time() > deadline:
            raise AssertionError(f"not true within {timeout} s: {getattr(check, '__name__', check)}")
        await asyncio.sleep(interval)
