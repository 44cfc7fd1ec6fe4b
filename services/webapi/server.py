"""The web API's HTTP server: the routes (`routes.Api`) on ``[webapi] host`` and ``port``, for a
robot client the service has opened (`__main__`), until the service stops."""

from __future__ import annotations

import asyncio
import contextlib

import zenoh
from aiohttp import web

from icefloe.client import AsyncRobot

from .routes import Api, ServerLog

KEEPALIVE_S = 15.0
"""An idle HTTP connection is closed after this long, s."""


async def serve(robot: AsyncRobot, guest: zenoh.Session | None = None) -> None:
    """Serve HTTP until cancelled (SIGINT/SIGTERM)."""
    settings = robot.config.webapi
    api = Api(robot, guest)
    # No access log; malformed requests become short rate-limited lines (ServerLog); an idle
    # connection is closed after KEEPALIVE_S (aiohttp keeps one an hour), so idle clients cost little.
    runner = web.AppRunner(api.app(), access_log=None, logger=ServerLog(robot.node.limited),
                           keepalive_timeout=KEEPALIVE_S)
    await runner.setup()
    # A short shutdown timeout: video streams never end by themselves.
    site = web.TCPSite(runner, settings.host, settings.port, shutdown_timeout=1.0)
    await site.start()
    robot.node.log.info("PenguinPi web API on http://%s:%d/", settings.host, settings.port)
    try:
        await api.follow()  # runs until SIGINT/SIGTERM cancels us
    finally:
        with contextlib.suppress(Exception):
            await robot.stop(confirm=False)  # whatever a client asked for, the robot stops with us
        await asyncio.shield(runner.cleanup())
