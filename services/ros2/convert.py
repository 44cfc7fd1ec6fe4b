"""icefloe's messages to ROS 2's and back, for the ros2 service (knows no bus)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from icefloe import ros2
from icefloe.config import RobotConfig
from icefloe.errors import ConfigError
from icefloe.schemas import keys
from icefloe.schemas import messages as m

ODOMETRY = "nav_msgs/msg/Odometry"
TWIST = "geometry_msgs/msg/Twist"


def ros_namespace(config: RobotConfig) -> str:
    """``ros2.namespace``, else ``/<robot name>``; a robot name ROS 2 cannot take is a ConfigError."""
    namespace = ros2.robot_namespace(config.name, config.ros2.namespace)
    if namespace is None:
        raise ConfigError(f"{config.source or config.name}: ros2.namespace: the robot's name {config.name!r} is "
                          f"not a ROS 2 name (a letter, then letters, digits, _); set ros2.namespace")
    return namespace


@dataclass(frozen=True)
class Frames:
    odom: str
    """``header.frame_id``: the frame the pose is in."""
    base: str
    """``child_frame_id``: the robot's body."""


class Odometry:
    """``odom/pose`` as nav_msgs/msg/Odometry in CDR. Covariances are zero: odometry gives none."""

    def __init__(self, distro: ros2.Distro, frames: Frames) -> None:
        self.distro, self.frames = distro, frames
        self._t = ros2.typestore(distro).types
        self._zero36 = np.zeros(36, dtype=np.float64)

    def message(self, pose: m.Pose) -> Any:
        t = self._t
        sec, nanosec = divmod(pose.stamp, 1_000_000_000)
        half = pose.theta / 2.0
        header = t["std_msgs/msg/Header"](t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                           frame_id=self.frames.odom)
        vector3, point = t["geometry_msgs/msg/Vector3"], t["geometry_msgs/msg/Point"]
        at = t["geometry_msgs/msg/Pose"](position=point(x=pose.x, y=pose.y, z=0.0),
                                        orientation=t["geometry_msgs/msg/Quaternion"](
                                            x=0.0, y=0.0, z=math.sin(half), w=math.cos(half)))
        moving = t["geometry_msgs/msg/Twist"](linear=vector3(x=pose.v, y=0.0, z=0.0),
                                             angular=vector3(x=0.0, y=0.0, z=pose.w))
        return t[ODOMETRY](header=header, child_frame_id=self.frames.base,
                           pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=at, covariance=self._zero36),
                           twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=moving, covariance=self._zero36))

    def cdr(self, pose: m.Pose) -> bytes:
        return ros2.to_cdr(self.message(pose), ODOMETRY, self.distro)


@dataclass(frozen=True)
class Output:
    """One ROS 2 topic the service publishes, made from one icefloe key's messages. The service
    publishes it, ``icefloe record --ros2`` records it: both go through this table."""

    key: keys.Topic
    """The icefloe key it is made from (several outputs may share one: ``odom`` and ``tf``)."""
    topic: str
    """Its ROS 2 name relative to the robot's namespace, e.g. ``odom``."""
    ros_type: str
    """Its ROS 2 type, e.g. ``nav_msgs/msg/Odometry``."""
    message: Callable[[Any], Any | None]
    """An icefloe message to the ROS 2 message (a rosbags object), or None: nothing to publish for it."""


def outputs(config: RobotConfig) -> list[Output]:
    """Every ROS 2 topic the robot's ``ros2`` config publishes, in the order the service declares them."""
    distro = config.ros2.distro
    odometry = Odometry(distro, Frames(config.ros2.odom_frame, config.ros2.base_frame))
    return [Output(keys.ODOM_POSE, "odom", ODOMETRY, odometry.message)]


def twist_command(payload: bytes, attachment: bytes | None, distro: ros2.Distro) -> m.Twist:
    """A geometry_msgs/msg/Twist sample (CDR) as icefloe's ``cmd/twist``: ``linear.x`` -> ``v``,
    ``angular.z`` -> ``w`` (a differential drive has no other motion). The attachment orders it:
    ``sender`` is the ROS 2 publisher's GID, ``seq`` and ``stamp`` its sequence number and source
    timestamp, so a stop on the bus wins over every ROS 2 command issued before it.
    Raises ValueError naming what is wrong."""
    twist = ros2.from_cdr(payload, TWIST, distro)
    v, w = float(twist.linear.x), float(twist.angular.z)
    if not (math.isfinite(v) and math.isfinite(w)):
        raise ValueError(f"linear.x {v} or angular.z {w} is not a finite number")
    if attachment is None:
        return m.Twist(v=v, w=w)  # a plain Zenoh put: ordered by when the robot's router saw it
    meta = ros2.Attachment.decode(attachment)
    if meta.seq < 0 or meta.stamp <= 0:
        raise ValueError(f"attachment's sequence number {meta.seq} or timestamp {meta.stamp} is negative or zero")
    return m.Twist(v=v, w=w, sender=f"ros2:{meta.gid.hex()}", seq=meta.seq, stamp=meta.stamp)
