"""ROS 2's Zenoh wire form, as rmw_zenoh writes it (ros2/rmw_zenoh docs/design.md; docs/ros2.md).

Nothing here touches the bus: the ros2 service (services/ros2) and its tests use these to build
the data keys, the per-sample attachment and the liveliness tokens ROS 2's graph tools read, and
to turn messages into CDR and back. Types, CDR and the REP 2016 type hashes come from `rosbags`
(its typestore of each distribution); no hash is pasted here.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING, Any, Literal

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

Distro = Literal["humble", "jazzy", "kilted", "rolling"]
DISTROS: tuple[Distro, ...] = ("humble", "jazzy", "kilted", "rolling")

ADMIN_SPACE = "@ros2_lv"
"""The prefix of every liveliness token: a Zenoh hermetic namespace (``*`` and ``**`` never match it)."""
HUMBLE_TYPE_HASH = "TypeHashNotSupported"
"""What rmw_zenoh's Humble branch writes where later distributions write a type hash (Humble has none)."""
CDR_LE_HEADER = b"\x00\x01\x00\x00"
"""CDR encapsulation header: plain CDR, little-endian; the first 4 bytes of every payload."""
ATTACHMENT = struct.Struct("<qqB16s")
"""The attachment of every sample: sequence number (int64 LE), source timestamp (ns since the epoch,
int64 LE), the GID's length (1 byte, always 16), the publisher's GID (16 bytes)."""
GID_LEN = 16

# The typestore of each distribution (rosbags: ROS2_ROLLING is not separate; its LATEST tracks Rolling).
_STORES = {"humble": "ROS2_HUMBLE", "jazzy": "ROS2_JAZZY", "kilted": "ROS2_KILTED", "rolling": "LATEST"}

DEFAULT_QOS = "::,10:,:,:,,"
"""rmw_zenoh's compact QoS (`qos_to_keyexpr`): every policy at its default (reliable, volatile, keep
last) but the depth, 10, which is what ``ros2 topic`` and rclpy's default profile use."""


@cache
def typestore(distro: Distro) -> Typestore:
    """The message types of one ROS 2 distribution, as rosbags ships them."""
    # Imported here: the router reads this module's names (its access rules) and need not load rosbags.
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores[_STORES[distro]])


def dds_type_name(ros_type: str) -> str:
    """``nav_msgs/msg/Odometry`` -> ``nav_msgs::msg::dds_::Odometry_`` (the name DDS and rmw_zenoh use)."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def type_hash(ros_type: str, distro: Distro) -> str:
    """REP 2016's ``RIHS01_<sha256>`` of a type, computed from the distribution's type description
    (rosbags' `Typestore.hash_rihs01`); on Humble the fixed text rmw_zenoh writes there."""
    if distro == "humble":
        return HUMBLE_TYPE_HASH
    return typestore(distro).hash_rihs01(ros_type)


def mangle(name: str) -> str:
    """A name in a liveliness token: each ``/`` becomes ``%``; an empty name is ``%``."""
    return name.replace("/", "%") if name else "%"


ROS_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
"""A name ROS 2 takes as one part of a namespace: a letter, then letters, digits, ``_``."""


def robot_namespace(robot: str, namespace: str = "") -> str | None:
    """The ROS 2 namespace of a robot's topics: ``namespace`` if set (the config's ``ros2.namespace``),
    else ``/<robot>``; None when the robot's name is not a ROS 2 name and no namespace is set."""
    if namespace:
        return namespace
    return f"/{robot}" if ROS_NAME.fullmatch(robot) else None


def qualified_name(namespace: str, topic: str) -> str:
    """The fully qualified name of a relative topic in a namespace: ``/penguin1`` + ``odom`` ->
    ``/penguin1/odom``."""
    if topic.startswith("/"):
        return topic
    return f"{namespace.rstrip('/')}/{topic}"


@dataclass(frozen=True)
class Endpoint:
    """One publisher or subscription of a node, with what ROS 2's graph shows of it."""

    domain: int
    namespace: str
    """The node's namespace, ``/penguin1`` ("" or ``/``: none)."""
    topic: str
    """Fully qualified, ``/penguin1/odom``."""
    ros_type: str
    """``nav_msgs/msg/Odometry``."""
    distro: Distro
    qos: str = DEFAULT_QOS

    @property
    def type_hash(self) -> str:
        return type_hash(self.ros_type, self.distro)

    @property
    def data_key(self) -> str:
        """``<domain>/<topic without its leading slash>/<DDS type name>/<type hash>``."""
        return f"{self.domain}/{self.topic.strip('/')}/{dds_type_name(self.ros_type)}/{self.type_hash}"


def node_token(domain: int, session_id: str, node_id: int, namespace: str, node: str) -> str:
    """``@ros2_lv/<domain>/<session>/<node id>/<node id>/NN/<enclave>/<namespace>/<node name>``."""
    return f"{ADMIN_SPACE}/{domain}/{session_id}/{node_id}/{node_id}/NN/%/{mangle(namespace.rstrip('/'))}/{node}"


def endpoint_token(endpoint: Endpoint, kind: Literal["MP", "MS"], session_id: str, node_id: int,
                   entity_id: int, node: str) -> str:
    """The token of a publisher (``MP``) or subscription (``MS``): the node's token with its own
    entity id and kind, then the mangled topic, the DDS type name, the type hash and the QoS."""
    ns = mangle(endpoint.namespace.rstrip("/"))
    return (f"{ADMIN_SPACE}/{endpoint.domain}/{session_id}/{node_id}/{entity_id}/{kind}/%/{ns}/{node}/"
            f"{mangle(endpoint.topic)}/{dds_type_name(endpoint.ros_type)}/{endpoint.type_hash}/{endpoint.qos}")


@dataclass(frozen=True)
class Attachment:
    """What rmw_zenoh attaches to every sample."""

    seq: int
    """The publisher's sequence number (from 1)."""
    stamp: int
    """Source timestamp, ns since the epoch."""
    gid: bytes
    """The publisher's GID, 16 bytes."""

    def encode(self) -> bytes:
        return ATTACHMENT.pack(self.seq, self.stamp, GID_LEN, self.gid)

    @staticmethod
    def decode(data: bytes) -> Attachment:
        """Raises ValueError naming what is wrong (length, GID length)."""
        if len(data) != ATTACHMENT.size:
            raise ValueError(f"attachment of {len(data)} bytes, not {ATTACHMENT.size}")
        seq, stamp, gid_len, gid = ATTACHMENT.unpack(data)
        if gid_len != GID_LEN:
            raise ValueError(f"attachment's GID length {gid_len}, not {GID_LEN}")
        return Attachment(seq, stamp, gid)


def to_cdr(message: Any, ros_type: str, distro: Distro) -> bytes:
    """A rosbags message object as CDR, little-endian, with its encapsulation header."""
    return bytes(typestore(distro).serialize_cdr(message, ros_type))


def from_cdr(payload: bytes, ros_type: str, distro: Distro) -> Any:
    """CDR (with its header) to a rosbags message object; raises ValueError when the bytes are not one."""
    if payload[:2] not in (b"\x00\x01", b"\x00\x00"):  # CDR_LE, CDR_BE: rosbags reads both
        raise ValueError(f"not a plain CDR encapsulation header: {payload[:4].hex() or 'empty'}")
    try:
        return typestore(distro).deserialize_cdr(payload, ros_type)
    except Exception as exc:  # rosbags raises struct.error, IndexError, UnicodeDecodeError...
        raise ValueError(f"{ros_type}: {exc or type(exc).__name__}") from None
