"""The robot's Zenoh router: the one process that listens on the robot's port.

Every service on the robot is a Zenoh client of this router, so no multicast is
needed; laptops connect to the same port. `icefloe up` starts it first. In a lab
the same command runs a router that robots and laptops join (see docs/lab.md).
"""

from __future__ import annotations

import asyncio

from .config import RobotConfig
from .runtime import run, zenoh_config
from .schemas import keys


async def main(config: RobotConfig) -> None:
    import zenoh

    session = zenoh.open(zenoh_config(config, mode="router", listen=config.zenoh.listen))
    token = session.liveliness().declare_token(keys.alive_key(config.name, "router"))
    print(f"router for {config.name!r} listening on {', '.join(config.zenoh.listen)}", flush=True)
    try:
        await asyncio.Event().wait()
    finally:
        token.undeclare()
        session.close()


if __name__ == "__main__":
    run(main, description="icefloe's Zenoh router")
