"""An independent ROS 2 user, for tests/test_ros2_service.py: zenoh-ros2-sdk (a pure-Python
rmw_zenoh client, not icefloe's code) in a process of its own.

    python tests/ros2_client.py PORT NAMESPACE

Prints one JSON line per event on stdout: ``{"keys": ...}`` once, ``{"odom": {...}}`` per Odometry
received, and likewise ``tf``, ``joint_states``, ``battery_state``, ``image`` (the compressed
image), ``camera_info`` and ``map`` per message of theirs. Reads commands on stdin, one per line:
``graph`` prints ``{"graph": [[topic, [types]], ...]}`` (what ``ros2 topic list -t`` shows);
``drive V W`` publishes geometry_msgs/msg/Twist on ``cmd_vel`` at 10 Hz; ``quiet`` stops
publishing; ``quit`` exits. The message definitions are common_interfaces' fields
(tests/ros2_msgs/, as a ROS 2 install has them, comments left out); the SDK computes its own
type hashes from them.
"""

from __future__ import annotations

import json
import math
import sys
import threading
import time
from pathlib import Path

from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber, get_registry, get_topic_names_and_types

MSGS = Path(__file__).parent / "ros2_msgs"


def say(**event: object) -> None:
    sys.stdout.write(json.dumps(event) + "\n")
    sys.stdout.flush()


def main() -> None:
    port, namespace = int(sys.argv[1]), sys.argv[2]
    get_registry(str(MSGS))  # the first call fixes the folder the SDK reads .msg files from
    where = {"router_ip": "127.0.0.1", "router_port": port, "domain_id": 0}

    def on_odom(msg) -> None:  # msg: a rosbags class the SDK made
        q = msg.pose.pose.orientation
        say(odom={"sec": msg.header.stamp.sec, "frame": msg.header.frame_id, "child": msg.child_frame_id,
                  "x": msg.pose.pose.position.x, "y": msg.pose.pose.position.y,
                  "theta": math.atan2(2 * q.w * q.z, 1 - 2 * q.z * q.z), "v": msg.twist.twist.linear.x})

    def on_tf(msg) -> None:
        (moved,) = msg.transforms
        say(tf={"frame": moved.header.frame_id, "child": moved.child_frame_id, "sec": moved.header.stamp.sec,
                "x": moved.transform.translation.x, "qz": moved.transform.rotation.z,
                "qw": moved.transform.rotation.w})

    def on_joints(msg) -> None:
        say(joint_states={"names": list(msg.name), "position": [float(v) for v in msg.position],
                          "velocity": [float(v) for v in msg.velocity], "sec": msg.header.stamp.sec})

    def on_battery(msg) -> None:
        say(battery_state={"voltage": float(msg.voltage), "current": float(msg.current),
                           "percentage_is_nan": math.isnan(msg.percentage), "status": msg.power_supply_status,
                           "sec": msg.header.stamp.sec})

    def on_image(msg) -> None:
        say(image={"format": msg.format, "size": len(msg.data), "head": bytes(msg.data[:4]).hex(),
                   "frame": msg.header.frame_id, "stamp": [msg.header.stamp.sec, msg.header.stamp.nanosec]})

    def on_info(msg) -> None:
        say(camera_info={"width": msg.width, "height": msg.height, "k": [float(v) for v in msg.k],
                         "model": msg.distortion_model, "frame": msg.header.frame_id,
                         "stamp": [msg.header.stamp.sec, msg.header.stamp.nanosec]})

    def on_map(msg) -> None:
        data = bytes(msg.data.astype("uint8"))
        say(map={"frame": msg.header.frame_id, "width": msg.info.width, "height": msg.info.height,
                 "resolution": float(msg.info.resolution), "occupied": data.count(100), "free": data.count(0)})

    sub = ROS2Subscriber(f"{namespace}/odom", "nav_msgs/msg/Odometry", on_odom, node_name="student_sub", **where)
    state = [ROS2Subscriber(f"{namespace}/{topic}", ros_type, callback, node_name="student_sub", **where)
             for topic, ros_type, callback in (
                 ("tf", "tf2_msgs/msg/TFMessage", on_tf),
                 ("joint_states", "sensor_msgs/msg/JointState", on_joints),
                 ("battery_state", "sensor_msgs/msg/BatteryState", on_battery),
                 ("camera/image_raw/compressed", "sensor_msgs/msg/CompressedImage", on_image),
                 ("camera/camera_info", "sensor_msgs/msg/CameraInfo", on_info),
                 ("map", "nav_msgs/msg/OccupancyGrid", on_map))]
    pub = ROS2Publisher(f"{namespace}/cmd_vel", "geometry_msgs/msg/Twist", node_name="student_drive", **where)
    say(keys={"odom": sub.keyexpr, "cmd_vel": pub.keyexpr, **{s.topic: s.keyexpr for s in state}})

    speed: list[float] | None = None
    lock = threading.Lock()

    def drive() -> None:
        vector3 = pub.session_mgr.store.types["geometry_msgs/msg/Vector3"]
        while True:
            with lock:
                now = speed
            if now is not None:
                pub.publish(linear=vector3(x=now[0], y=0.0, z=0.0), angular=vector3(x=0.0, y=0.0, z=now[1]))
            time.sleep(0.1)

    threading.Thread(target=drive, daemon=True).start()
    for line in sys.stdin:
        words = line.split()
        if words[:1] == ["drive"]:
            with lock:
                speed = [float(words[1]), float(words[2])]
        elif words[:1] == ["graph"]:  # as `ros2 topic list -t`, from the liveliness tokens
            say(graph=[[name, types] for name, types in get_topic_names_and_types(timeout=2.0, **where)])
        elif words[:1] == ["quiet"]:
            with lock:
                speed = None
        elif words[:1] == ["quit"]:
            break
        say(done=line.strip())
    for subscriber in (sub, *state):
        subscriber.close()
    pub.close()


if __name__ == "__main__":
    main()
