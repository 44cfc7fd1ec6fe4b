"""The ros2 service as a real process on the simulated robot, seen and driven by an independent
rmw_zenoh client (zenoh-ros2-sdk, tests/ros2_client.py, a process of its own): the graph lists the
robot's topics with their types, ``odom`` arrives as nav_msgs/msg/Odometry, ``cmd_vel`` moves the
simulator's truth, the deadman stands it when the client goes quiet, and a stop on the bus stops
it; hostile ``cmd_vel`` puts (late, replayed, wildcard, bad bytes, bad attachment, another robot's
namespace, a flood) move nothing. Measured 7-9 s (load 3), the machine's other work beside it."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

from conftest import wait_for
from webapi_helpers import sim_state, still

from icefloe import ros2
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.ros2.convert import TWIST

CLIENT = Path(__file__).parent / "ros2_client.py"


class Client:
    """tests/ros2_client.py in a process of its own; its JSON lines collected."""

    def __init__(self, port: int, namespace: str) -> None:
        self.proc = subprocess.Popen([sys.executable, str(CLIENT), str(port), namespace], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.events: list[dict] = []
        self.lines: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:  # type: ignore[union-attr]
            self.lines.append(line)
            if line.startswith("{"):
                self.events.append(json.loads(line))

    def send(self, line: str) -> None:
        self.proc.stdin.write(line + "\n")  # type: ignore[union-attr]
        self.proc.stdin.flush()  # type: ignore[union-attr]

    def of(self, kind: str) -> list:
        return [e[kind] for e in self.events if kind in e]

    async def wait(self, kind: str, count: int = 1, timeout: float = 30.0) -> list:
        try:
            await wait_for(lambda: len(self.of(kind)) >= count or self.proc.poll() is not None, timeout)
        except AssertionError:
            raise AssertionError(f"no {kind} from the ROS 2 client:\n{''.join(self.lines)[-3000:]}") from None
        assert self.proc.poll() is None, "".join(self.lines)[-3000:]
        return self.of(kind)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.send("quit")
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


async def test_a_ros2_client_sees_odom_and_drives_the_simulated_robot(robot) -> None:
    for service in ("sim", "hwbridge", "odometry"):
        robot.start(service)
    service = robot.start("ros2")
    namespace = f"/{robot.name}"
    client = Client(robot.port, namespace)
    try:
        async with robot.node("tester") as node:
            # odom arrives as nav_msgs/msg/Odometry, decoded by the client's own CDR and type hash.
            odom = (await client.wait("odom"))[-1]
            assert (odom["frame"], odom["child"]) == ("odom", "base_link")
            assert abs(odom["sec"] - time.time()) < 60
            keys_seen = client.of("keys")[0]
            assert keys_seen["odom"] == ros2.Endpoint(0, namespace, f"{namespace}/odom", "nav_msgs/msg/Odometry",
                                                      "jazzy").data_key
            # the graph, from the liveliness tokens, as `ros2 topic list -t` shows it
            client.send("graph")
            graph = dict((await client.wait("graph"))[0])
            assert graph[f"{namespace}/odom"] == ["nav_msgs/msg/Odometry"]
            assert graph[f"{namespace}/cmd_vel"] == ["geometry_msgs/msg/Twist"]

            # cmd_vel drives the simulated robot; odom follows.
            start = await sim_state(node)
            client.send("drive 0.15 0.0")
            for _ in range(300):
                if (await sim_state(node)).x > start.x + 0.05:
                    break
                await asyncio.sleep(0.1)
            else:
                raise AssertionError(f"the truth did not move: {await sim_state(node)}\n{service.output[-2000:]}")
            await wait_for(lambda: client.of("odom")[-1]["x"] > odom["x"] + 0.03, timeout=20)

            # The client goes quiet: the deadman stands the wheels, with no stop.
            client.send("quiet")
            quiet = await still(node)

            async def moved_from(x: float) -> None:
                for _ in range(300):
                    if (await sim_state(node)).x > x + 0.03:
                        return
                    await asyncio.sleep(0.1)
                raise AssertionError(f"the truth did not move: {await sim_state(node)}\n{service.output[-2000:]}")

            # Driving again, then a stop on the bus stops it (the client quiet first: a ROS 2 command
            # issued after the stop would rightly drive again). Stopped means the wheels stand.
            client.send("drive 0.15 0.0")
            await moved_from(quiet.x)
            client.send("quiet")
            node.publisher(keys.STOP).put(node.command(m.Stop))
            await still(node)

            # Hostile cmd_vel puts move nothing, and the service says why and keeps running.
            ros = node.session
            twist = ros2.typestore("jazzy").types
            vec = twist["geometry_msgs/msg/Vector3"]
            fast = ros2.to_cdr(twist[TWIST](linear=vec(x=0.3, y=0.0, z=0.0), angular=vec(x=0.0, y=0.0, z=0.0)),
                               TWIST, "jazzy")
            data_key = ros2.Endpoint(0, namespace, f"{namespace}/cmd_vel", TWIST, "jazzy").data_key
            # One ROS 2 publisher (GID "g"): a command, then a stop, then its command issued before that stop
            # arriving late (as a stalled network delivers it): the stop wins. Replayed, it is refused too.
            gid = b"g" * 16
            issued = time.time_ns()
            ros.put(data_key, fast, attachment=ros2.Attachment(1, issued, gid).encode())
            node.publisher(keys.STOP).put(node.command(m.Stop))
            stopped = await still(node)
            ros.put(data_key, fast, attachment=ros2.Attachment(2, issued + 1_000_000, gid).encode())
            ros.put(data_key, fast, attachment=ros2.Attachment(1, issued, gid).encode())
            ros.put("0/*/cmd_vel/**", fast, attachment=ros2.Attachment(1, time.time_ns(), b"x" * 16).encode())
            ros.put(data_key, b"\x00\x01\x00\x00bad", attachment=ros2.Attachment(2, time.time_ns(),
                                                                                  b"y" * 16).encode())
            ros.put(data_key, fast, attachment=b"short")
            ros.put(f"0/other{robot.name}/cmd_vel/{ros2.dds_type_name(TWIST)}/{ros2.type_hash(TWIST, 'jazzy')}",
                    fast, attachment=ros2.Attachment(3, time.time_ns(), b"z" * 16).encode())
            await wait_for(lambda: "wildcard" in service.output or "commands only on" in service.output, 20)
            await wait_for(lambda: "attachment of 5 bytes" in service.output, 20)
            # A flood of bad cmd_vel: a few lines a second, not one per sample, and the service runs on.
            lines_before = service.output.count("dropped a cmd_vel")
            for i in range(2000):
                ros.put(data_key, b"\x00\x01\x00\x00" + bytes([i % 256]))
            await asyncio.sleep(1.0)  # what a refused command could have done: it would show in 1 s
            after = await still(node)
            assert abs(after.x - stopped.x) < 1e-3, (stopped, after)
            assert service.alive(), service.output[-2000:]
            assert service.output.count("dropped a cmd_vel") - lines_before < 40, service.output[-3000:]
    finally:
        client.close()
