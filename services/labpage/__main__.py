"""The lab's page: ``python -m icefloe.services.labpage --config lab.toml`` (see the package's docstring).

Wiring only: the TA's session on the lab router, the robots' hwbridge tokens and ``hw/hold``
into the roster, the HTTP routes (`page`) on ``[lab] page_host`` and ``page_port``.
"""

from __future__ import annotations

import asyncio
import contextlib

import zenoh
from aiohttp import web

from icefloe import labstop
from icefloe.config import RobotConfig
from icefloe.errors import BadPayload, IcefloeError
from icefloe.runtime import Node, run
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m

from .page import LabPage, StopRequest, login_of
from .roster import Roster


async def main(config: RobotConfig) -> None:
    folder, ta_config, login = login_of(config)
    roster = Roster(folder.robots)
    async with Node("labpage", ta_config, announce=False) as node:  # the TA holds no token
        loop = asyncio.get_running_loop()

        def on_token(sample: zenoh.Sample) -> None:  # a Zenoh thread: the roster is the loop's
            loop.call_soon_threadsafe(roster.token, str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

        def on_hold(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            try:
                hold = codec.decode(sample.payload.to_bytes(), str(sample.encoding), m.Hold, key)
            except BadPayload as exc:
                node.limited.warning("bad hw/hold", "dropped: %s", exc)
                return
            loop.call_soon_threadsafe(roster.hold, key, hold)

        tokens = node.session.liveliness().declare_subscriber(keys.alive_key("*", "hwbridge"), on_token,
                                                              history=True)
        node.on_samples(keys.key("*", keys.HOLD), on_hold)

        async def stopper(body: StopRequest, robots: list[str]) -> list[labstop.Answer]:
            request = node.command(m.LabStop, action=body.action, reason=body.reason,
                                   owner_may_release=body.owner_may_release, timeout=config.lab.timeout)
            answers = await labstop.ask(node.session, robots or roster.known(), request)
            return sorted(answers, key=lambda a: a.robot)

        page = LabPage(login, roster, stopper, config.lab.timeout, node.limited)
        runner = web.AppRunner(page.app(), access_log=None)
        await runner.setup()
        site = web.TCPSite(runner, config.lab.page_host, config.lab.page_port, shutdown_timeout=1.0)
        try:
            await site.start()
        except OSError as exc:
            await runner.cleanup()
            raise IcefloeError(f"lab.page_port {config.lab.page_port}: {exc.strerror or exc}") from None
        node.log.info("the lab's page on http://%s:%d/ (%d robots of %s; the TA's login)", config.lab.page_host,
                      config.lab.page_port, len(folder.robots), config.lab.folder)
        try:
            await asyncio.Event().wait()
        finally:
            tokens.undeclare()
            with contextlib.suppress(Exception):
                await asyncio.shield(runner.cleanup())


if __name__ == "__main__":
    run(main)
