"""The PenguinPi web API service: ``python -m icefloe.services.webapi --config ...``.

Serves HTTP on ``[webapi] host`` and ``port`` (all interfaces, 8080; ``host = "127.0.0.1"``
for this machine only) and talks to the robot over the bus. On a robot with access control
the routes that change anything need the robot's user and password (`auth`).
Timed motions (``/robot/set/velocity?...&time=``) are ``cmd/motion`` queries:
hwbridge runs the ramp and answers when the wheels have been told to stop.
"""

from __future__ import annotations

import math

import msgspec

from icefloe.client import AsyncRobot
from icefloe.config import RobotConfig
from icefloe.errors import ConfigError
from icefloe.runtime import open_session, run

from .server import serve


async def main(config: RobotConfig) -> int | None:
    if config.zenoh.access_control and not config.zenoh.user:
        raise ConfigError(f"{config.source}: webapi: access control is on but the robot has no credentials "
                          f"({config.zenoh.credentials or 'zenoh.credentials is not set'}): nobody could "
                          "command it")
    # A short timeout for bus waits: an HTTP client should hear "not answering" soon. clamp: the
    # old server let the board clamp demands up to 100 (0.53 m/s); hwbridge clamps them the same.
    # follow=False: the state the routes read is subscribed to only while they read it (`state`).
    robot = AsyncRobot(config=config, service="webapi", timeout=2.0, clamp=True, follow=False)
    guest = None
    try:
        await robot.open(connect_timeout=math.inf)  # a service waits for its router to come up
        if config.zenoh.access_control:
            # The HTTP bridge acts for guests through a session logged in as the guest, so the
            # router checks them as it checks any guest (`routes.Api.caller`).
            anyone = msgspec.structs.replace(config.zenoh, user="", password="")
            guest = await open_session(msgspec.structs.replace(config, zenoh=anyone))
        await serve(robot, guest)
    finally:
        if guest is not None:
            guest.close()
        await robot.close()  # stops the wheels if a client had set them moving


if __name__ == "__main__":
    run(main)
