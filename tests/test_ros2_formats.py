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
import struct
from pathlib import Path

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
