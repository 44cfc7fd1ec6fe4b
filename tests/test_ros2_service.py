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
STATE_TOPICS = {"tf": "tf2_msgs/msg/TFMessage", "joint_states": "sensor_msgs/msg/JointState",
                "battery_state": "sensor_msgs/msg/BatteryState", "pose": "geometry_msgs/msg/PoseWithCovarianceStamped",
                "external_pose": "geometry_msgs/msg/PoseWithCovarianceStamped",
                "camera/landmarks": "visualization_msgs/msg/MarkerArray",
                "camera/camera_info": "sensor_msgs/msg/CameraInfo",
                "camera/image_raw/compressed": "sensor_msgs/msg/CompressedImage"}
"""The topics besides odom and cmd_vel that the graph lists (and map, where the grid service runs)."""
STACK = ("sim", "hwbridge", "odometry", "power", "grid", "ros2")


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


async def test_a_ros2_client_sees_odom_and_drives_the_simulated_robot(make_robot) -> None:
    robot = make_robot(f"services = {list(STACK)}\n[ros2]\nmap_period_s = 1.0")
    for service in STACK[:-1]:
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
            assert {topic: graph.get(f"{namespace}/{topic}") for topic in [*STATE_TOPICS, "map"]} == \
                {topic: [ros_type] for topic, ros_type in {**STATE_TOPICS, "map": "nav_msgs/msg/OccupancyGrid"}.items()}

            # the state topics, each decoded by the client: tf and joint_states from the simulated
            # wheels (hwbridge, odometry), battery_state from the power service
            tf = (await client.wait("tf"))[-1]
            assert (tf["frame"], tf["child"]) == ("odom", "base_link") and abs(tf["sec"] - time.time()) < 60
            joints = (await client.wait("joint_states"))[-1]
            assert joints["names"] == ["left_wheel_joint", "right_wheel_joint"]
            battery = (await client.wait("battery_state"))[-1]
            assert 6.0 < battery["voltage"] < 9.0 and battery["percentage_is_nan"], battery
            # the camera's topics from its key (no camera process: it renders, which costs seconds here)
            jpeg = b"\xff\xd8\xff\xe0" + bytes(1000) + b"\xff\xd9"
            shot = m.Image(stamp=time.time_ns(), width=320, height=240, data=jpeg)
            node.publisher(keys.IMAGE).put(shot)
            image, info = (await client.wait("image"))[-1], (await client.wait("camera_info"))[-1]
            assert (image["format"], image["size"], image["head"], image["frame"]) == \
                ("jpeg", len(jpeg), "ffd8ffe0", "camera_optical_frame")
            assert info["stamp"] == image["stamp"] == list(divmod(shot.stamp, 1_000_000_000))
            assert (info["width"], info["height"], info["model"]) == (320, 240, "plumb_bob")
            assert info["k"][0] == 250.0  # sim.toml's focal_px 500 at 640x480, for the 320x240 image
            # map: the grid service's answer, asked again every map_period_s (a subscriber who joins late gets it)
            grid = await node.query(keys.MAP_GRID, m.GridRequest())
            world = (await client.wait("map"))[-1]
            assert (world["frame"], world["width"], world["height"]) == ("map", grid.width, grid.height)
            assert world["occupied"] == grid.cells.count(1) > 0 and world["free"] == grid.cells.count(0)

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
            await wait_for(lambda: client.of("tf")[-1]["x"] > tf["x"] + 0.03, timeout=20)
            await wait_for(lambda: all(p > p0 + 0.5 for p, p0 in zip(client.of("joint_states")[-1]["position"],
                                                                      joints["position"], strict=True)), timeout=20)

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
            ros, wheels = node.session, node.latest(keys.WHEELS)
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
            # The stop only once hwbridge drives that command: it goes through the ros2 service, the stop
            # straight to hwbridge, and a command first heard after the stop is taken as issued after it.
            await wait_for(lambda: (w := wheels.get()) is not None and w.target_left > 0.1, 20)
            node.publisher(keys.STOP).put(node.command(m.Stop))
            stopped = await still(node)
            ros.put(data_key, fast, attachment=ros2.Attachment(2, issued + 1_000, gid).encode())
            ros.put(data_key, fast, attachment=ros2.Attachment(1, issued, gid).encode())
            ros.put("0/*/cmd_vel/**", fast, attachment=ros2.Attachment(1, time.time_ns(), b"x" * 16).encode())
            ros.put(data_key, b"\x00\x01\x00\x00bad", attachment=ros2.Attachment(2, time.time_ns(),
                                                                                  b"y" * 16).encode())
            ros.put(data_key, fast, attachment=b"short")
            ros.put(f"0/other{robot.name}/cmd_vel/{ros2.dds_type_name(TWIST)}/{ros2.type_hash(TWIST, 'jazzy')}",
                    fast, attachment=ros2.Attachment(3, time.time_ns(), b"z" * 16).encode())
            await wait_for(lambda: "wildcard" in service.output or "commands only on" in service.output, 20)
            await wait_for(lambda: "attachment of 5 bytes" in service.output, 20)
            # State the service cannot turn into ROS 2's: one line naming the key and the field, and on it runs.
            node.publisher(keys.LOC_POSE).put(m.PoseEstimate(stamp=time.time_ns(), x=0.0, y=0.0, theta=0.0,
                                                             covariance=[1.0]))
            node.publisher(keys.LANDMARKS).put(m.Landmarks(stamp=time.time_ns(), landmarks=[
                m.Landmark(id=-5, range=1.0, bearing=0.0)]))
            await wait_for(lambda: "loc/pose: covariance: 1 numbers, not 9" in service.output, 20)
            await wait_for(lambda: "camera/landmarks: landmarks: id -5" in service.output, 20)
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
