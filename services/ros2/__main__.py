"""The ros2 service: the robot's state out (``odom``, ``tf``, ``joint_states``, ...) and ``cmd_vel``
in, as rmw_zenoh writes them (docs/ros2.md).

    python -m icefloe.services.ros2 --config deploy/robots/sim.toml

A ROS 2 node ``icefloe`` in the robot's namespace (``/<robot>``): a publisher for each of
`convert.outputs` (``odom``: nav_msgs/msg/Odometry from ``odom/pose``, ...; ``map`` from the grid
service's answer, asked again every ``ros2.map_period_s``) and its subscription to ``cmd_vel``
(geometry_msgs/msg/Twist, put on ``cmd/twist`` for hwbridge, which applies the stops and the
deadman to it as to any command). Liveliness tokens make them appear in ``ros2 node list`` and
``ros2 topic list -t``. A message that cannot be turned into its ROS 2 form is left out with one
rate-limited line naming the key and the field; the service runs on.
"""

from __future__ import annotations

import asyncio
import itertools
import os
import time
from collections.abc import Callable
from typing import Any

import zenoh

from icefloe import ros2
from icefloe.config import RobotConfig
from icefloe.errors import BadPayload, NotReachable
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

        def declare(output: Output, endpoint: ros2.Endpoint) -> Callable[[Any], None]:
            """A publisher of one output: its own GID and sequence (rmw_zenoh's GIDs are as opaque: unique
            per publisher). The function it returns publishes one icefloe message, if it makes one."""
            publisher = node.session.declare_publisher(endpoint.data_key,
                                                       congestion_control=zenoh.CongestionControl.DROP)
            gid, seq = os.urandom(ros2.GID_LEN), itertools.count(1)

            def put(msg: Any) -> None:
                try:
                    payload = output.message(msg)
                    if payload is None:
                        return
                    cdr = ros2.to_cdr(payload, output.ros_type, distro)
                except (ValueError, TypeError, OverflowError) as exc:  # a message we cannot turn: the next may do
                    node.limited.warning(output.topic, "not published on %s: a %s on %s: %s", endpoint.topic,
                                         output.key.type.__name__, node.key(output.key), exc)
                    return
                attachment = ros2.Attachment(next(seq), time.time_ns(), gid).encode()  # when published
                publisher.put(cdr, attachment=attachment)

            return put

        async def publish(key: keys.Topic, these: list[tuple[Output, ros2.Endpoint]]) -> None:
            """Each message of ``key`` as each of its outputs."""
            puts = [declare(output, endpoint) for output, endpoint in these]
            async for msg in node.subscribe(key):
                for put in puts:
                    put(msg)

        async def ask(output: Output, endpoint: ros2.Endpoint) -> None:
            """A queryable's answer (the grid service's ``map/grid``), asked every ``output.period`` s:
            volatile QoS keeps no sample for a ROS 2 user who joins later, so it comes again."""
            put = declare(output, endpoint)
            said = False
            while True:
                try:
                    put(await node.query(output.key, output.request, timeout=2.0))
                except BadPayload as exc:  # an answer that is no OccupancyGrid: asked again next time
                    node.limited.warning(output.topic, "not published on %s: %s", endpoint.topic, exc)
                except NotReachable as exc:
                    if not said:  # once: the grid service may start after us, or not at all
                        node.log.warning("%s: nothing yet for %s, asking every %g s: %s", node.key(output.key),
                                         endpoint.topic, output.period, exc)
                        said = True
                await asyncio.sleep(output.period)

        by_key: dict[keys.Topic, list[tuple[Output, ros2.Endpoint]]] = {}
        for output, endpoint in out:
            by_key.setdefault(output.key, []).append((output, endpoint))
        node.log.info("ROS 2 (%s, domain %d): publishing %s, subscribed to %s", distro, domain,
                      ", ".join(endpoint.data_key for _, endpoint in out), cmd_vel.data_key)
        async with asyncio.TaskGroup() as tasks:
            tasks.create_task(drive())
            for key, these in by_key.items():
                if key.kind == "query":
                    for output, endpoint in these:
                        tasks.create_task(ask(output, endpoint))
                else:
                    tasks.create_task(publish(key, these))
        del tokens


if __name__ == "__main__":
    run(main)
