"""The ros2 service as a real process on a guarded simulated robot (``zenoh.access_control``), seen
and driven through the robot's router by an independent rmw_zenoh client logged in as the robot's
owner (zenoh-ros2-sdk, tests/ros2_client.py, a process of its own): the graph lists the robot's
topics with their types, ``odom`` arrives as nav_msgs/msg/Odometry, ``cmd_vel`` moves the
simulator's truth, the deadman stands it when the client goes quiet, and a stop on the bus stops
it. Hostile ``cmd_vel`` puts (late, replayed, wildcard, bad bytes, bad attachment, another robot's
namespace, a flood) move nothing; a ROS 2 client logged in as the guest reads ``odom`` but its
``cmd_vel`` moves nothing; no login, a wrong one, another robot's owner's are refused; tokens that
would show a node or topic in another robot's namespace are dropped by the router.
Measured 7-9 s (load 3), the machine's other work beside it."""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh
from conftest import wait_for
from webapi_helpers import sim_state, still

from icefloe import ros2
from icefloe.credentials import GUEST_PASSWORD, GUEST_USER, make, read
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.ros2.convert import TWIST
from icefloe.vision.geometry import Intrinsics

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

    def __init__(self, port: int, namespace: str, user: str, password: str) -> None:
        # As docs/ros2.md tells a ROS 2 user to connect to a guarded robot: a client of its router, logged in.
        login = (f'mode="client";transport/auth/usrpwd/user="{user}";'
                 f'transport/auth/usrpwd/password="{password}"')
        self.proc = subprocess.Popen([sys.executable, str(CLIENT), str(port), namespace], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                     env={**os.environ, "ZENOH_CONFIG_OVERRIDE": login})
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


def login(port: int, user: str = "", password: str = "") -> zenoh.Session:
    """A plain Zenoh session to the robot's router, as a ROS 2 user's would be: logged in, or not."""
    zc = zenoh.Config()
    zc.insert_json5("mode", '"client"')
    zc.insert_json5("scouting/multicast/enabled", "false")
    zc.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    if user:
        zc.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
        zc.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    return zenoh.open(zc)


async def test_a_ros2_client_sees_odom_and_drives_the_simulated_robot(make_robot, tmp_path: Path) -> None:
    robot = make_robot(f"services = {list(STACK)}\n[ros2]\nmap_period_s = 1.0", access_control=True)
    owner = read(robot.credentials_path)
    for service in STACK[:-1]:
        robot.start(service)
    service = robot.start("ros2")
    namespace = f"/{robot.name}"
    client = Client(robot.port, namespace, owner.user, owner.password)
    guest_client = Client(robot.port, namespace, GUEST_USER, GUEST_PASSWORD)  # a classmate's ROS 2, read-only
    guest = login(robot.port, GUEST_USER, GUEST_PASSWORD)
    intruder = login(robot.port, GUEST_USER, GUEST_PASSWORD)  # another: a session hears its own puts and tokens
    heard: list[str] = []  # what the router passes on to the guest of every robot's ROS 2 data
    gids: list[bytes] = []  # the GIDs of the cmd_vel publishers it passes on (an attachment's last 16 bytes)
    data_key = ros2.Endpoint(0, namespace, f"{namespace}/cmd_vel", TWIST, "jazzy").data_key

    def on_sample(sample: zenoh.Sample) -> None:
        heard.append(str(sample.key_expr))
        attachment = sample.attachment.to_bytes() if sample.attachment is not None else b""
        if str(sample.key_expr) == data_key and len(attachment) == ros2.ATTACHMENT.size:
            gids.append(attachment[-ros2.GID_LEN:])

    spy = guest.declare_subscriber("0/**", on_sample)
    try:
        async with robot.node("tester") as node:  # the robot's own login, as its services have
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
            shipped = Intrinsics.from_config(robot.config.camera)  # sim.toml's calibration, at 640x480
            assert info["k"][0] == pytest.approx(shipped.camera_matrix[0, 0] / 2)  # for the 320x240 image
            # map: the grid service's answer, asked again every map_period_s (a subscriber who joins late gets it)
            grid = await node.query(keys.MAP_GRID, m.GridRequest())
            world = (await client.wait("map"))[-1]
            assert (world["frame"], world["width"], world["height"]) == ("map", grid.width, grid.height)
            assert world["occupied"] == grid.cells.count(1) > 0 and world["free"] == grid.cells.count(0)
            await guest_client.wait("odom")  # the guest reads the robot's topics too

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
            heard.clear()
            gids.clear()
            ros.put(data_key, fast, attachment=ros2.Attachment(2, issued + 1_000_000, gid).encode())
            ros.put(data_key, fast, attachment=ros2.Attachment(1, issued, gid).encode())
            # A wildcard within the robot's own namespace passes the router: the service drops it.
            ros.put(f"0{namespace}/cmd_vel/**", fast, attachment=ros2.Attachment(1, time.time_ns(), b"x" * 16).encode())
            ros.put(data_key, b"\x00\x01\x00\x00bad", attachment=ros2.Attachment(2, time.time_ns(),
                                                                                  b"y" * 16).encode())
            ros.put(data_key, fast, attachment=b"short")
            # Wildcards that reach beyond it, and another robot's namespace: the router drops them, even the
            # owner's. The guest's spy on 0/** hears a marker put after them, and none of them before it.
            other = f"0/other{robot.name}/cmd_vel/{ros2.dds_type_name(TWIST)}/{ros2.type_hash(TWIST, 'jazzy')}"
            refused = ["0/**", "0/*/cmd_vel/**", "**", other, f"0/{robot.name}$*/cmd_vel/**"]
            for key in refused:
                ros.put(key, fast, attachment=ros2.Attachment(3, time.time_ns(), b"z" * 16).encode())
            marker = f"0{namespace}/marker"
            ros.put(marker, b"")
            # The guest may put on nothing: not by hand, not with ROS 2 (its client drives meanwhile).
            intruder.put(data_key, fast, attachment=ros2.Attachment(1, time.time_ns(), b"h" * 16).encode())
            guest_client.send("drive 0.3 0.0")
            await wait_for(lambda: marker in heard, 20)
            assert not set(refused) & set(heard), heard
            await wait_for(lambda: "commands only on" in service.output, 20)
            await wait_for(lambda: "attachment of 5 bytes" in service.output, 20)
            # State the service cannot turn into ROS 2's: one line naming the key and the field, and on it runs.
            node.publisher(keys.LOC_POSE).put(m.PoseEstimate(stamp=time.time_ns(), x=0.0, y=0.0, theta=0.0,
                                                             covariance=[1.0]))
            node.publisher(keys.LANDMARKS).put(m.Landmarks(stamp=time.time_ns(), landmarks=[
                m.Landmark(id=-5, range=1.0, bearing=0.0)]))
            await wait_for(lambda: "loc/pose: covariance: 1 numbers, not 9" in service.output, 20)
            await wait_for(lambda: "camera/landmarks: landmarks: id -5" in service.output, 20)
            # No login, a wrong one, another robot's owner's: the router takes no session at all.
            other_owner = read(make(tmp_path / "other.credentials", f"other{robot.name}")[0])
            for user, password in (("", ""), (owner.user, "not the password"),
                                   (other_owner.user, other_owner.password)):
                with pytest.raises(zenoh.ZError):
                    login(robot.port, user, password).close()
            # A flood of bad cmd_vel: a few lines a second, not one per sample, and the service runs on.
            lines_before = service.output.count("dropped a cmd_vel")
            for i in range(2000):
                ros.put(data_key, b"\x00\x01\x00\x00" + bytes([i % 256]))
            await guest_client.wait("done")  # it drives (10 Hz) from here on
            await asyncio.sleep(1.0)  # what a refused command could have done: it would show in 1 s
            guest_client.send("quiet")
            after = await still(node)
            assert abs(after.x - stopped.x) < 1e-3, (stopped, after)
            assert (after.duty_left, after.duty_right) == (0.0, 0.0), after  # the board's PWM stood too
            # The guest's puts never passed the router: only the owner's publishers' GIDs were heard.
            assert set(gids) <= {b"g" * 16, b"x" * 16, b"y" * 16}, set(gids)
            assert service.alive(), service.output[-2000:]
            assert service.output.count("dropped a cmd_vel") - lines_before < 40, service.output[-3000:]

            # Tokens that would show a node or a topic in another robot's namespace are dropped by the router;
            # the owner's own (its node in the robot's namespace, the last) and the robot's service's pass.
            zid = str(ros.zid())
            spoofs = [ros2.node_token(0, zid, 7, f"/other{robot.name}", "icefloe"),
                      ros2.endpoint_token(ros2.Endpoint(0, "", f"/other{robot.name}/odom", TWIST, "jazzy"), "MP", zid,
                                          8, 1, "teleop")]
            held = [ros.liveliness().declare_token(token) for token in spoofs]
            held.append(intruder.liveliness().declare_token(ros2.node_token(0, str(intruder.zid()), 0, namespace,
                                                                            "fake")))
            # The owner's own token, declared last, is in the graph once the owner's spoofs (and the guest's,
            # declared earlier) have had their chance.
            mine = ros2.node_token(0, zid, 9, namespace, "student")
            held.append(ros.liveliness().declare_token(mine))

            def graph() -> set[str]:  # as rmw_zenoh reads it when it starts: a liveliness query
                return {str(r.ok.key_expr) for r in guest.liveliness().get("@ros2_lv/0/**", timeout=5.0)
                        if r.ok is not None}

            for _ in range(100):
                graph_tokens = await asyncio.to_thread(graph)
                if mine in graph_tokens:
                    break
                await asyncio.sleep(0.1)
            assert mine in graph_tokens and any("/NN/%/" + ros2.mangle(namespace) + "/icefloe" in t
                                                for t in graph_tokens), graph_tokens
            assert not [t for t in graph_tokens if f"other{robot.name}" in t or t.endswith("/fake")], graph_tokens
            for token in held:
                token.undeclare()
    finally:
        spy.undeclare()
        guest.close()
        intruder.close()
        client.close()
        guest_client.close()
