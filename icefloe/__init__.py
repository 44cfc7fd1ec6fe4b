"""icefloe: the software stack of a small education robot.

For students who do not want to learn Zenoh on day one::

    from icefloe import Robot
    with Robot("sim") as robot:
        robot.set_velocity(0.1, 0.1, duration=2.0)
        print(robot.pose)
"""

from __future__ import annotations

from typing import Any

__all__ = ["AsyncRobot", "Robot"]


def __getattr__(name: str) -> Any:
    # Imported on first use: the services import `icefloe.runtime` and need none of the client.
    if name in __all__:
        from . import client

        return getattr(client, name)
    raise AttributeError(f"module 'icefloe' has no attribute {name!r}")
