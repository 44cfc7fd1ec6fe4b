"""rmw_zenoh's wire form (icefloe/ros2.py) against values rmw_zenoh and ROS 2 published.

References (docs/ros2.md lists them):
* ros2/rmw_zenoh docs/design.md (rolling, the form Jazzy's and Kilted's releases use): the data key
  ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c74...`` and the liveliness tokens of
  demo_nodes_cpp's talker and listener, the 33-byte attachment.
* the type hashes of geometry_msgs/msg/Twist and nav_msgs/msg/Odometry as Jazzy's rmw_zenoh writes them
  in keys seen on the wire (``0/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_9c45bf16...``,
  ``0/robot1/odom/nav_msgs::msg::dds_::Odometry_/RIHS01_3cc97dc7...``).
"""

from __future__ import annotations

import math
import re
import struct
from pathlib import Path

import msgspec
import numpy as np
import pytest

from icefloe import ros2
from icefloe.schemas import messages as m
from icefloe.services.ros2.convert import ODOMETRY, TWIST, Frames, Odometry, twist_command

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
TWIST_HASH = "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
ODOMETRY_HASH = "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0"


@pytest.mark.parametrize("distro", ["jazzy", "kilted", "rolling"])
def test_type_hashes_are_computed_as_ros2_publishes_them(distro) -> None:
    assert ros2.type_hash("std_msgs/msg/String", distro) == STRING_HASH
    assert ros2.type_hash(TWIST, distro) == TWIST_HASH
    assert ros2.type_hash(ODOMETRY, distro) == ODOMETRY_HASH


def test_humble_keys_carry_no_hash() -> None:
    odom = ros2.Endpoint(0, "/robot1", "/robot1/odom", ODOMETRY, "humble")
    assert odom.data_key == "0/robot1/odom/nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported"


def test_data_keys_as_design_md_shows_them() -> None:
    chatter = ros2.Endpoint(0, "", "/chatter", "std_msgs/msg/String", "jazzy")
    assert chatter.data_key == f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    namespaced = ros2.Endpoint(0, "/robot1", ros2.qualified_name("/robot1", "chatter"), "std_msgs/msg/String",
                               "jazzy")
    assert namespaced.data_key == f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    assert ros2.Endpoint(3, "/p1", "/p1/cmd_vel", TWIST, "jazzy").data_key == \
        f"3/p1/cmd_vel/geometry_msgs::msg::dds_::Twist_/{TWIST_HASH}"


def test_liveliness_tokens_as_design_md_shows_them() -> None:
    """design.md's tokens of demo_nodes_cpp's listener (domain 2, its subscription entity 10, depth 10)
    and talker (depth 7): the same text, character for character."""
    zid = "aac3178e146ba6f1fc6e6a4085e77f21"
    assert ros2.node_token(2, zid, 0, "", "listener") == f"@ros2_lv/2/{zid}/0/0/NN/%/%/listener"
    chatter = ros2.Endpoint(2, "", "/chatter", "std_msgs/msg/String", "jazzy")
    assert ros2.endpoint_token(chatter, "MS", zid, 0, 10, "listener") == (
        f"@ros2_lv/2/{zid}/0/10/MS/%/%/listener/%chatter/std_msgs::msg::dds_::String_/{STRING_HASH}/::,10:,:,:,,")
    talker = "8b20917502ee955ac4476e0266340d5c"
    depth7 = ros2.Endpoint(2, "", "/chatter", "std_msgs/msg/String", "jazzy", qos="::,7:,:,:,,")
    assert ros2.endpoint_token(depth7, "MP", talker, 0, 10, "talker") == (
        f"@ros2_lv/2/{talker}/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,")
    # in a namespace: the namespace and the topic mangled ('/' -> '%')
    odom = ros2.Endpoint(0, "/penguin1", "/penguin1/odom", ODOMETRY, "jazzy")
    assert ros2.node_token(0, zid, 0, "/penguin1", "icefloe") == f"@ros2_lv/0/{zid}/0/0/NN/%/%penguin1/icefloe"
    assert ros2.endpoint_token(odom, "MP", zid, 0, 1, "icefloe").startswith(
        f"@ros2_lv/0/{zid}/0/1/MP/%/%penguin1/icefloe/%penguin1%odom/nav_msgs::msg::dds_::Odometry_/")


def test_attachment_is_design_mds_33_bytes() -> None:
    gid = bytes(range(16))
    data = ros2.Attachment(7, 1_700_000_000_123_456_789, gid).encode()
    assert len(data) == 33
    assert data == struct.pack("<q", 7) + struct.pack("<q", 1_700_000_000_123_456_789) + b"\x10" + gid
    assert ros2.Attachment.decode(data) == ros2.Attachment(7, 1_700_000_000_123_456_789, gid)
    for bad in (b"", data[:-1], data + b"\0", data[:16] + b"\x08" + gid):
        with pytest.raises(ValueError, match="attachment"):
            ros2.Attachment.decode(bad)


def test_odometry_in_cdr() -> None:
    pose = m.Pose(stamp=1_700_000_001_250_000_000, x=1.5, y=-0.25, theta=math.pi / 2, v=0.1, w=-0.3)
    payload = Odometry("jazzy", Frames("odom", "base_link")).cdr(pose)
    assert payload[:4] == ros2.CDR_LE_HEADER
    back = ros2.from_cdr(payload, ODOMETRY, "jazzy")
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == (1_700_000_001, 250_000_000)
    assert (back.header.frame_id, back.child_frame_id) == ("odom", "base_link")
    assert (back.pose.pose.position.x, back.pose.pose.position.y) == (1.5, -0.25)
    q = back.pose.pose.orientation
    assert math.atan2(2 * q.w * q.z, 1 - 2 * q.z * q.z) == pytest.approx(math.pi / 2)
    assert (back.twist.twist.linear.x, back.twist.twist.angular.z) == (0.1, -0.3)


def _twist_cdr(v: float, w: float) -> bytes:
    t = ros2.typestore("jazzy").types
    vec = t["geometry_msgs/msg/Vector3"]
    return ros2.to_cdr(t[TWIST](linear=vec(x=v, y=0.0, z=0.0), angular=vec(x=0.0, y=0.0, z=w)), TWIST, "jazzy")


def test_cmd_vel_becomes_an_ordered_command() -> None:
    gid = bytes(range(16))
    cmd = twist_command(_twist_cdr(0.2, -0.5), ros2.Attachment(3, 1_700_000_000_000_000_000, gid).encode(), "jazzy")
    assert cmd == m.Twist(v=0.2, w=-0.5, sender="ros2:" + gid.hex(), seq=3, stamp=1_700_000_000_000_000_000)
    assert twist_command(_twist_cdr(0.1, 0.0), None, "jazzy") == m.Twist(v=0.1, w=0.0)


@pytest.mark.parametrize("payload, attachment, why", [
    (b"", None, "header"),
    (b"\x00\x01\x00\x00\x01", None, "Twist"),                          # truncated
    (b"\x01\x00\x00\x00" + b"\0" * 48, None, "header"),                 # not plain CDR
    (_twist_cdr(math.nan, 0.0), None, "finite"),
    (_twist_cdr(0.0, math.inf), None, "finite"),
    (_twist_cdr(0.1, 0.0), b"\0" * 5, "attachment"),
    (_twist_cdr(0.1, 0.0), ros2.Attachment(-1, 5, bytes(16)).encode(), "negative"),
    (_twist_cdr(0.1, 0.0), ros2.Attachment(1, 0, bytes(16)).encode(), "zero"),
])
def test_bad_cmd_vel_is_refused_with_a_reason(payload, attachment, why) -> None:
    with pytest.raises(ValueError, match=why):
        twist_command(payload, attachment, "jazzy")


def test_the_namespace_and_a_bad_ros2_config(tmp_path) -> None:
    from icefloe import config as config_mod
    from icefloe.errors import ConfigError
    from icefloe.services.ros2.convert import ros_namespace

    sim = Path(__file__).parents[1] / "deploy" / "robots" / "sim.toml"

    def load(text: str):
        path = tmp_path / "r.toml"
        path.write_text(f'extends = "{sim}"\n{text}\n')
        return config_mod.load(path)

    assert ros_namespace(load('name = "penguin1"')) == "/penguin1"
    assert ros_namespace(load('name = "pen-1"\n[ros2]\nnamespace = "/lab/pen1"')) == "/lab/pen1"
    with pytest.raises(ConfigError, match=r"ros2\.namespace: the robot's name 'pen-1' is not a ROS 2 name"):
        ros_namespace(load('name = "pen-1"'))
    for bad, field in (('distro = "iron"', "ros2.distro"), ("domain_id = 233", "ros2.domain_id"),
                       ('namespace = "lab/*"', "ros2.namespace"), ('odom_frame = "a b"', "ros2.odom_frame")):
        with pytest.raises(ConfigError, match=field):
            load(f"[ros2]\n{bad}")


# ---------------------------------------------------------------- the state topics (convert.outputs)

# Published values of the new types' hashes (Jazzy; Kilted and Rolling give the same), as
# `ros2 topic info --verbose` of ROS 2 installs prints them (users' notes: /tf of Nav2's amcl,
# /joint_states, a BatteryState subscription, RViz's /map subscription) or as Jazzy's
# share/sensor_msgs/msg/CompressedImage.json holds it (quoted in a project); CameraInfo,
# PoseWithCovarianceStamped and MarkerArray as other rmw_zenoh implementations' golden tables
# carry them (no ROS 2 install's output seen for them). docs/ros2.md says which is which.
PUBLISHED_HASHES = {
    "tf2_msgs/msg/TFMessage": "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "sensor_msgs/msg/JointState": "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    "sensor_msgs/msg/BatteryState": "RIHS01_4bee5dfce981c98faa6828b868307a0a73f992ed0789f374ee96c8f840e69741",
    "nav_msgs/msg/OccupancyGrid": "RIHS01_8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7",
    "sensor_msgs/msg/CompressedImage": "RIHS01_15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a",
    "sensor_msgs/msg/CameraInfo": "RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275",
    "geometry_msgs/msg/PoseWithCovarianceStamped":
        "RIHS01_26432f9803e43727d3c8f668d1fdb3c630f548af631e2f4e31382371bfea3b6e",
    "visualization_msgs/msg/MarkerArray": "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf",
}
STAMP = 1_700_000_001_250_000_000


def sim_config(tmp_path, text: str = ""):
    from icefloe import config as config_mod

    sim = Path(__file__).parents[1] / "deploy" / "robots" / "sim.toml"
    path = tmp_path / "r.toml"
    path.write_text(f'extends = "{sim}"\nname = "penguin1"\n{text}\n')
    return config_mod.load(path)


def by_topic(config) -> dict:
    from icefloe.services.ros2.convert import outputs

    return {output.topic: output for output in outputs(config)}


def round_trip(output, msg, distro: ros2.Distro = "jazzy"):
    """``msg`` through the output's conversion, to CDR and back: what a ROS 2 subscriber decodes."""
    return ros2.from_cdr(ros2.to_cdr(output.message(msg), output.ros_type, distro), output.ros_type, distro)


@pytest.mark.parametrize("distro", ["jazzy", "kilted", "rolling"])
def test_new_types_hash_as_published(distro) -> None:
    for ros_type, published in PUBLISHED_HASHES.items():
        assert ros2.type_hash(ros_type, distro) == published, ros_type


def test_the_table_names_each_topic_its_key_and_type(tmp_path) -> None:
    from icefloe.schemas import keys

    table = by_topic(sim_config(tmp_path))
    assert {topic: (o.key, o.ros_type) for topic, o in table.items()} == {
        "odom": (keys.ODOM_POSE, ODOMETRY),
        "tf": (keys.ODOM_POSE, "tf2_msgs/msg/TFMessage"),
        "joint_states": (keys.WHEELS, "sensor_msgs/msg/JointState"),
        "battery_state": (keys.BATTERY, "sensor_msgs/msg/BatteryState"),
        "pose": (keys.LOC_POSE, "geometry_msgs/msg/PoseWithCovarianceStamped"),
        "external_pose": (keys.EXTLOC_POSE, "geometry_msgs/msg/PoseWithCovarianceStamped"),
        "camera/landmarks": (keys.LANDMARKS, "visualization_msgs/msg/MarkerArray"),
        "camera/camera_info": (keys.IMAGE, "sensor_msgs/msg/CameraInfo"),
        "camera/image_raw/compressed": (keys.IMAGE, "sensor_msgs/msg/CompressedImage"),
    }
    # the camera's every frame only when asked; none when off; map only where the grid service runs
    frames = by_topic(sim_config(tmp_path, '[ros2]\nimages = "frames"'))
    assert frames["camera/image_raw/compressed"].key == frames["camera/camera_info"].key == keys.FRAMES
    off = by_topic(sim_config(tmp_path, '[ros2]\nimages = "off"'))
    assert "camera/image_raw/compressed" not in off and off["camera/camera_info"].key == keys.IMAGE
    with_grid = by_topic(sim_config(tmp_path, 'services = ["sim", "hwbridge", "grid", "ros2"]\n'
                                              '[ros2]\nmap_period_s = 2.5'))
    assert (with_grid["map"].key, with_grid["map"].period, with_grid["map"].request) == \
        (keys.MAP_GRID, 2.5, m.GridRequest())
    # every topic a ROS 2 name in the robot's namespace, every type one ROS 2 has
    for output in with_grid.values():
        assert re.fullmatch(r"[a-z][a-z_]*(/[a-z][a-z_]*)*", output.topic), output.topic
        assert output.ros_type in ros2.typestore("jazzy").types


def test_tf_is_odom_to_base_link(tmp_path) -> None:
    tf = round_trip(by_topic(sim_config(tmp_path))["tf"],
                    m.Pose(stamp=STAMP, x=1.5, y=-0.25, theta=-math.pi / 2, v=0.1, w=0.0))
    (moved,) = tf.transforms
    assert (moved.header.frame_id, moved.child_frame_id) == ("odom", "base_link")
    assert (moved.header.stamp.sec, moved.header.stamp.nanosec) == (1_700_000_001, 250_000_000)
    assert (moved.transform.translation.x, moved.transform.translation.y, moved.transform.translation.z) == \
        (1.5, -0.25, 0.0)
    q = moved.transform.rotation
    assert (q.x, q.y) == (0.0, 0.0) and q.w**2 + q.z**2 == pytest.approx(1.0)
    assert 2 * math.atan2(q.z, q.w) == pytest.approx(-math.pi / 2)
    framed = by_topic(sim_config(tmp_path, '[ros2]\nodom_frame = "penguin1/odom"\nbase_frame = "penguin1/base"'))
    moved = round_trip(framed["tf"], m.Pose(stamp=STAMP, x=0.0, y=0.0, theta=0.0)).transforms[0]
    assert (moved.header.frame_id, moved.child_frame_id) == ("penguin1/odom", "penguin1/base")


def test_joint_states_are_wheel_angles_and_rates(tmp_path) -> None:
    config = sim_config(tmp_path, "[geometry]\nwheel_diameter = 0.065\nticks_per_rev = 384")
    wheels = m.Wheels(stamp=STAMP, ticks_left=384 * 3 + 96, ticks_right=-192, speed_left=0.13, speed_right=-0.065)
    joints = round_trip(by_topic(config)["joint_states"], wheels)
    assert list(joints.name) == ["left_wheel_joint", "right_wheel_joint"]
    assert joints.position == pytest.approx([3.25 * 2 * math.pi, -math.pi])  # rad, unwrapped
    assert joints.velocity == pytest.approx([0.13 / 0.0325, -2.0])  # rad/s: rim speed over the radius
    assert len(joints.effort) == 0 and joints.header.frame_id == ""
    assert (joints.header.stamp.sec, joints.header.stamp.nanosec) == (1_700_000_001, 250_000_000)


def test_battery_state_has_ros2s_sign_and_nan_for_what_is_not_measured(tmp_path) -> None:
    output = by_topic(sim_config(tmp_path))["battery_state"]
    battery = round_trip(output, m.Battery(stamp=STAMP, voltage=7.6, current=0.42, state="low"))
    assert battery.voltage == pytest.approx(7.6) and battery.current == pytest.approx(-0.42)  # discharging
    assert battery.power_supply_status == battery.POWER_SUPPLY_STATUS_DISCHARGING and battery.present
    for unmeasured in ("percentage", "charge", "capacity", "design_capacity", "temperature"):
        assert math.isnan(getattr(battery, unmeasured)), unmeasured
    idle = round_trip(output, m.Battery(stamp=STAMP, voltage=8.1, current=0.0, state="ok"))
    assert idle.power_supply_status == idle.POWER_SUPPLY_STATUS_UNKNOWN
    assert (idle.header.stamp.sec, idle.header.stamp.nanosec) == (1_700_000_001, 250_000_000)


@pytest.mark.parametrize("topic, pose", [
    ("pose", m.PoseEstimate(stamp=STAMP, x=2.0, y=1.0, theta=math.pi, covariance=[0.01, 0.002, 0.003,
                                                                                  0.002, 0.02, 0.004,
                                                                                  0.003, 0.004, 0.05])),
    ("external_pose", m.ExternalPose(stamp=STAMP, x=2.0, y=1.0, theta=math.pi, covariance=[0.01, 0.002, 0.003,
                                                                                          0.002, 0.02, 0.004,
                                                                                          0.003, 0.004, 0.05])),
])
def test_poses_in_the_map_frame_with_their_covariance(tmp_path, topic, pose) -> None:
    config = sim_config(tmp_path, '[ros2]\nmap_frame = "world"')
    out = round_trip(by_topic(config)[topic], pose)
    assert out.header.frame_id == "world" and out.header.stamp.sec == 1_700_000_001
    assert (out.pose.pose.position.x, out.pose.pose.position.y) == (2.0, 1.0)
    q = out.pose.pose.orientation
    assert abs(2 * math.atan2(q.z, q.w)) == pytest.approx(math.pi)
    six = np.asarray(out.pose.covariance).reshape(6, 6)
    assert six[np.ix_([0, 1, 5], [0, 1, 5])] == pytest.approx(np.asarray(pose.covariance).reshape(3, 3))
    assert six[2:5, :].sum() == 0 and six[:, 2:5].sum() == 0  # z, roll, pitch: none on the floor
    with pytest.raises(ValueError, match="covariance: 4 numbers, not 9"):
        by_topic(config)[topic].message(msgspec.structs.replace(pose, covariance=[1.0, 0.0, 0.0, 1.0]))


def test_map_is_the_grid_as_ros2_percentages(tmp_path) -> None:
    config = sim_config(tmp_path, 'services = ["grid", "ros2"]')
    cells = bytes([0, 1, 0, 0, 0, 1])  # 3 columns, 2 rows, row 0 (y = origin) first
    grid = m.OccupancyGrid(stamp=STAMP, world="lab", resolution=0.05, origin_x=-1.0, origin_y=-0.5, width=3,
                           height=2, inflation=0.0, cells=cells)
    out = round_trip(by_topic(config)["map"], grid)
    assert out.header.frame_id == "map" and out.info.map_load_time.sec == 1_700_000_001
    assert (out.info.width, out.info.height) == (3, 2) and out.info.resolution == pytest.approx(0.05)
    assert (out.info.origin.position.x, out.info.origin.position.y, out.info.origin.orientation.w) == \
        (-1.0, -0.5, 1.0)
    assert list(out.data) == [0, 100, 0, 0, 0, 100]
    with pytest.raises(ValueError, match="cells: 5 bytes, not width x height = 6"):
        by_topic(config)["map"].message(msgspec.structs.replace(grid, cells=cells[:5]))


def test_compressed_image_is_the_cameras_jpeg_untouched(tmp_path) -> None:
    jpeg = b"\xff\xd8\xff\xe0" + bytes(range(256)) + b"\xff\xd9"
    out = round_trip(by_topic(sim_config(tmp_path))["camera/image_raw/compressed"],
                     m.Image(stamp=STAMP, width=320, height=240, data=jpeg))
    assert (out.format, bytes(out.data)) == ("jpeg", jpeg)
    assert (out.header.frame_id, out.header.stamp.sec, out.header.stamp.nanosec) == \
        ("camera_optical_frame", 1_700_000_001, 250_000_000)


def test_camera_info_is_the_calibration_at_the_images_size(tmp_path) -> None:
    from icefloe.vision.geometry import Intrinsics, save_calibration

    k = np.array([[610.0, 0.0, 322.0], [0.0, 605.0, 238.5], [0.0, 0.0, 1.0]])
    save_calibration(tmp_path / "cal.yaml", Intrinsics(k, np.array([0.1, -0.2, 0.001, 0.002, 0.05]), 640, 480))
    config = sim_config(tmp_path, f'[camera]\ncalibration = "{tmp_path / "cal.yaml"}"\n'
                                  '[ros2]\ncamera_frame = "cam_optical"')
    image = m.Image(stamp=STAMP, width=320, height=240, data=b"\xff\xd8")
    info = round_trip(by_topic(config)["camera/camera_info"], image)
    assert (info.header.frame_id, info.header.stamp.sec, info.header.stamp.nanosec) == \
        ("cam_optical", 1_700_000_001, 250_000_000)  # the image's stamp: the two are paired by it
    assert (info.width, info.height, info.distortion_model) == (320, 240, "plumb_bob")
    # half the size: focal lengths halved, the principal point about pixel centres ((c + 0.5) / 2 - 0.5)
    assert info.k == pytest.approx([305.0, 0.0, 160.75, 0.0, 302.5, 119.0, 0.0, 0.0, 1.0])
    assert info.p == pytest.approx([305.0, 0.0, 160.75, 0.0, 0.0, 302.5, 119.0, 0.0, 0.0, 0.0, 1.0, 0.0])
    assert info.d == pytest.approx([0.1, -0.2, 0.001, 0.002, 0.05]) and info.r == pytest.approx(np.eye(3).ravel())
    # the nominal camera (no calibration): focal_px, the centre, no distortion, as the camera answers camera/info
    no_file = sim_config(tmp_path, '[camera]\nfocal_px = 500.0\ncalibration = ""')  # not sim.toml's file
    nominal = round_trip(by_topic(no_file)["camera/camera_info"], image)
    assert nominal.k == pytest.approx([250.0, 0.0, 159.5, 0.0, 250.0, 119.5, 0.0, 0.0, 1.0])
    assert list(nominal.d) == [0.0] * 5
    with pytest.raises(ValueError, match="width x height: 0 x 240"):
        by_topic(config)["camera/camera_info"].message(msgspec.structs.replace(image, width=0))


def test_landmarks_are_markers_with_their_ids(tmp_path) -> None:
    config = sim_config(tmp_path, "[camera]\nmarker_size = 0.1")
    output = by_topic(config)["camera/landmarks"]
    seen = m.Landmarks(stamp=STAMP, landmarks=[
        m.Landmark(id=7, range=1.0, bearing=0.1, position=[0.1, -0.02, 0.99], rotation=[0.0, math.pi / 2, 0.0]),
        m.Landmark(id=12, range=2.0, bearing=math.pi / 2),  # range and bearing only
    ])
    out = round_trip(output, seen)
    clear, marker, flat = out.markers
    assert (clear.action, clear.header.frame_id) == (clear.DELETEALL, "camera_optical_frame")  # the last frame's go
    assert (marker.id, marker.ns, marker.action, marker.type) == (7, "aruco", marker.ADD, marker.CUBE)
    assert marker.header.frame_id == "camera_optical_frame" and marker.header.stamp.sec == 1_700_000_001
    assert (marker.pose.position.x, marker.pose.position.y, marker.pose.position.z) == (0.1, -0.02, 0.99)
    q = marker.pose.orientation  # a quarter turn about the camera's y
    assert (q.x, q.y, q.z, q.w) == pytest.approx((0.0, math.sin(math.pi / 4), 0.0, math.cos(math.pi / 4)))
    assert (marker.scale.x, marker.scale.y) == (0.1, 0.1)
    assert (flat.id, flat.type, flat.header.frame_id) == (12, flat.CYLINDER, "base_link")
    assert (flat.pose.position.x, flat.pose.position.y) == pytest.approx((0.0, 2.0))
    assert len(round_trip(output, m.Landmarks(stamp=STAMP, landmarks=[])).markers) == 1  # nothing seen: clear
    for bad, why in ((m.Landmark(id=-1, range=1.0, bearing=0.0), "id -1"),
                     (m.Landmark(id=3, range=1.0, bearing=0.0, position=[1.0], rotation=[]), "marker 3")):
        with pytest.raises(ValueError, match=why):
            output.message(m.Landmarks(stamp=STAMP, landmarks=[bad]))


def test_the_new_ros2_settings_and_their_ranges(tmp_path) -> None:
    from icefloe.errors import ConfigError

    ros = sim_config(tmp_path).ros2
    assert (ros.map_frame, ros.camera_frame, ros.images, ros.map_period_s) == \
        ("map", "camera_optical_frame", "image", 5.0)
    for bad, field in (('map_frame = "a b"', "ros2.map_frame"), ('camera_frame = "cam*"', "ros2.camera_frame"),
                       ('images = "all"', "ros2.images"), ("map_period_s = 0", "ros2.map_period_s"),
                       ("map_period_s = -1.0", "ros2.map_period_s"), ("map_period_s = 1e9", "ros2.map_period_s")):
        with pytest.raises(ConfigError, match=field):
            sim_config(tmp_path, f"[ros2]\n{bad}")
