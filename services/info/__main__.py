"""The info service: the smallest complete icefloe service, and a model for your own.

    python -m icefloe.services.info --config deploy/robots/sim.toml
    icefloe query info
"""

from __future__ import annotations

import asyncio

from icefloe.config import RobotConfig, robot_info
from icefloe.runtime import Node, run
from icefloe.schemas import keys
from icefloe.schemas import messages as m


async def main(config: RobotConfig) -> None:
    info = robot_info(config)

    async def answer(_request: m.Stop) -> m.RobotInfo:
        return info

    async with Node("info", config) as node:
        node.queryable(keys.INFO, answer)
        node.log.info("serving %s", node.key(keys.INFO))
        await asyncio.Event().wait()  # until SIGINT/SIGTERM cancels us


if __name__ == "__main__":
    run(main)
