"""The ros2 service: the robot's state out (``odom``, ...) and ``cmd_vel`` in, as rmw_zenoh writes
them (docs/ros2.md).

    python -m icefloe.services.ros2 --config deploy/robots/sim.toml

A ROS 2 node ``icefloe`` in the robot's namespace (``/<robot>``): a publisher for each of
`convert.outputs` (``odom``: nav_msgs/msg/Odometry from ``odom/pose``, ...) and its subscription to ``cmd_vel``
(geometry_msgs/msg/Twist, put on ``cmd/twist`` for hwbridge, which applies the stops and the
deadman to it as to any command). Liveliness tokens make them appear in ``ros2 node list`` and
``ros2 topic list -t``.
"""

from __future__ import annotations

import asyncio
import itertools
import os
import time

import zenoh

from icefloe import ros2
from icefloe.config import RobotConfig
from icefloe.runtime import Node, run
from icefloe.schemas import keys

from .convert import TWIST, Output, outputs, ros_namespace, twist_command

NODE_NAME = "icefloe"


async def main(config: RobotConfig) -> None:
    ns, distro = ros_namespace(config), config.ros2.distro
    domain = config.ros2.domain_id
    out = [(output, ros2.Endpoint(domain, ns, ros2.qualified_name(ns, output.topic), output.ros_type, distro))
           for output in outputs(config)]
    cmd_vel = ros2.Endpoint(domain, ns, ros2.qualified_name(ns, "cmd_vel"), TWIST, distro)
    loop = asyncio.get_running_loop()
    commands: asyncio.Queue[tuple[bytes, bytes | None]] = asyncio.Queue(maxsize=64)

    async with Node("ros2", config) as node:
        session_id = str(node.session.zid())
        liveliness = node.session.liveliness()
        # Held until the session closes (which withdraws them): ROS 2's graph sees the node while it runs.
        tokens = [liveliness.declare_token(token) for token in (
            ros2.node_token(domain, session_id, 0, ns, NODE_NAME),
            *(ros2.endpoint_token(endpoint, "MP", session_id, 0, 1 + i, NODE_NAME)
              for i, (_, endpoint) in enumerate(out)),
            ros2.endpoint_token(cmd_vel, "MS", session_id, 0, 1 + len(out), NODE_NAME))]
        twist = node.publisher(keys.TWIST)

        def on_cmd_vel(sample: zenoh.Sample) -> None:  # our reader thread: never block
            key = str(sample.key_expr)
            if key != cmd_vel.data_key:  # put on a wildcard, e.g. 0/*/cmd_vel/**: not ours alone
                node.limited.warning("cmd_vel", "dropped a cmd_vel put on %s: commands only on %s", key,
                                     cmd_vel.data_key)
                return
            attachment = sample.attachment.to_bytes() if sample.attachment is not None else None
            item = (sample.payload.to_bytes(), attachment)
            loop.call_soon_threadsafe(_offer, item)

        def _offer(item: tuple[bytes, bytes | None]) -> None:
            if commands.full():  # a flood: keep the newest, a command is stale behind 64 others
                commands.get_nowait()
                node.limited.warning("cmd_vel", "cmd_vel: more than %d commands waiting; dropped the oldest",
                                     commands.maxsize)
            commands.put_nowait(item)

        node.on_samples(cmd_vel.data_key, on_cmd_vel)

        async def drive() -> None:
            while True:
                payload, attachment = await commands.get()
                try:
                    twist.put(twist_command(payload, attachment, distro))
                except ValueError as exc:
                    node.limited.warning("cmd_vel", "dropped a cmd_vel on %s: %s", cmd_vel.data_key, exc)

        async def publish(key: keys.Topic, these: list[tuple[Output, ros2.Endpoint]]) -> None:
            """Each message of ``key`` as each of its outputs; a GID and a sequence per publisher (rmw_zenoh's
            GIDs are as opaque: unique per publisher)."""
            publishers = [(output, node.session.declare_publisher(
                endpoint.data_key, congestion_control=zenoh.CongestionControl.DROP), os.urandom(ros2.GID_LEN),
                itertools.count(1)) for output, endpoint in these]
            async for msg in node.subscribe(key):
                for output, publisher, gid, seq in publishers:
                    message = output.message(msg)
                    if message is None:
                        continue
                    attachment = ros2.Attachment(next(seq), time.time_ns(), gid).encode()  # when published
                    publisher.put(ros2.to_cdr(message, output.ros_type, distro), attachment=attachment)

        by_key: dict[keys.Topic, list[tuple[Output, ros2.Endpoint]]] = {}
        for output, endpoint in out:
            by_key.setdefault(output.key, []).append((output, endpoint))
        node.log.info("ROS 2 (%s, domain %d): publishing %s, subscribed to %s", distro, domain,
                      ", ".join(endpoint.data_key for _, endpoint in out), cmd_vel.data_key)
        async with asyncio.TaskGroup() as tasks:
            tasks.create_task(drive())
            for key, these in by_key.items():
                tasks.create_task(publish(key, these))
        del tokens


if __name__ == "__main__":
    run(main)
