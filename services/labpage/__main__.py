"""The lab's page: ``python -m icefloe.services.labpage --config lab.toml`` (see the package's docstring).

Wiring only: the TA's session on the lab router, the robots' hwbridge tokens and ``hw/hold``
into the roster, the HTTP routes (`page`) on ``[lab] page_host`` and ``page_port``.
"""

from __future__ import annotations

import asyncio
import contextlib
from pathlib import Path

import zenoh
from aiohttp import web

from icefloe import labstop
from icefloe.config import RobotConfig
from icefloe.errors import BadPayload, ConfigError, IcefloeError
from icefloe.runtime import Node, run
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m

from .page import LabPage, Login, StopRequest
from .roster import Roster


def login_of(config: RobotConfig) -> tuple[labstop.LabFolder, RobotConfig, Login]:
    """The lab's folder, the config logged in as its TA, and the TA's login for the page;
    `ConfigError` (one line) for a lab config the page cannot work with."""
    if not config.lab.folder:
        raise ConfigError(f"{config.source}: lab.folder is not set: the page needs the lab's credentials folder "
                          "(its robots, and the TA's credentials file)")
    folder = labstop.lab_folder(Path(config.lab.folder), config.name)
    if not folder.ta:
        raise ConfigError(f"{config.lab.folder}: no TA credentials file (robot = \"*\", docs/lab.md): the page "
                          "logs in as the lab's TA")
    ta_config, _ = labstop.ta_config(config, folder)
    return folder, ta_config, Login(ta_config.zenoh.user, ta_config.zenoh.password)


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
