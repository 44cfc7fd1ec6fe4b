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

from . import camera, state

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

    @staticmethod
    def pose(odometry: Any) -> m.Pose:
        """The other way (replaying a ROS 2 recording): a nav_msgs/msg/Odometry as ``odom/pose``; the
        heading is the quaternion's yaw (a differential drive turns about z only)."""
        stamp = int(odometry.header.stamp.sec) * 1_000_000_000 + int(odometry.header.stamp.nanosec)
        q, at = odometry.pose.pose.orientation, odometry.pose.pose.position
        theta = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        moving = odometry.twist.twist
        return m.Pose(stamp=stamp, x=float(at.x), y=float(at.y), theta=theta, v=float(moving.linear.x),
                      w=float(moving.angular.z))


@dataclass(frozen=True)
class Output:
    """One ROS 2 topic the service publishes, made from one icefloe key's messages. The service
    publishes it, ``icefloe record --ros2`` records it: both go through this table."""

    key: keys.Topic
    """The icefloe key it is made from (several outputs may share one: ``odom`` and ``tf``). For a
    queryable (``map/grid``: ``key.kind == "query"``) its answer, asked every `period` s."""
    topic: str
    """Its ROS 2 name relative to the robot's namespace, e.g. ``odom``."""
    ros_type: str
    """Its ROS 2 type, e.g. ``nav_msgs/msg/Odometry``."""
    message: Callable[[Any], Any | None]
    """An icefloe message to the ROS 2 message (a rosbags object), or None: nothing to publish for it.
    Raises ValueError naming the field of a message it cannot turn."""
    period: float = 0.0
    """For a queryable `key` only: ask it this often, s (0 for a key that is published)."""
    request: m.Message | None = None
    """For a queryable `key` only: what to ask it."""


def outputs(config: RobotConfig) -> list[Output]:
    """Every ROS 2 topic the robot's ``ros2`` config publishes, in the order the service declares them.

    ``camera/image_raw/compressed`` follows ``ros2.images`` (not there when "off"); ``map`` is there
    only when the robot runs the grid service (``services`` names "grid")."""
    ros, distro = config.ros2, config.ros2.distro
    odometry = Odometry(distro, Frames(ros.odom_frame, ros.base_frame))
    images = keys.FRAMES if ros.images == "frames" else keys.IMAGE
    table = [
        Output(keys.ODOM_POSE, "odom", ODOMETRY, odometry.message),
        Output(keys.ODOM_POSE, "tf", state.TF, state.Transform(distro, ros.odom_frame, ros.base_frame).message),
        Output(keys.WHEELS, "joint_states", state.JOINT_STATE,
               state.WheelJoints(distro, config.geometry.wheel_diameter, config.geometry.ticks_per_rev).message),
        Output(keys.BATTERY, "battery_state", state.BATTERY_STATE, state.Battery(distro).message),
        Output(keys.LOC_POSE, "pose", state.POSE_WITH_COVARIANCE, state.MapPose(distro, ros.map_frame).message),
        Output(keys.EXTLOC_POSE, "external_pose", state.POSE_WITH_COVARIANCE,
               state.MapPose(distro, ros.map_frame).message),
        Output(keys.LANDMARKS, "camera/landmarks", camera.MARKER_ARRAY,
               camera.LandmarkMarkers(distro, ros.camera_frame, ros.base_frame, config.camera.marker_size).message),
        Output(images, "camera/camera_info", camera.CAMERA_INFO,
               camera.CameraInfo(distro, ros.camera_frame, config.camera).message),
    ]
    if ros.images != "off":
        table.append(Output(images, "camera/image_raw/compressed", camera.COMPRESSED_IMAGE,
                            camera.CompressedImage(distro, ros.camera_frame).message))
    if "grid" in config.services:
        table.append(Output(keys.MAP_GRID, "map", state.OCCUPANCY_GRID, state.Map(distro, ros.map_frame).message,
                            period=ros.map_period_s, request=m.GridRequest()))
    return table


@dataclass(frozen=True)
class Input:
    """One ROS 2 topic of a recording turned back into an icefloe key's messages (``icefloe replay``
    of an ``icefloe record --ros2`` recording)."""

    topic: str
    """Its ROS 2 name relative to the robot's namespace, e.g. ``odom``."""
    ros_type: str
    key: keys.Topic
    """The icefloe key its messages go back to."""
    message: Callable[[Any], Any]
    """The ROS 2 message (a rosbags object) to icefloe's; raises ValueError naming what is wrong."""


CMD_VEL = "cmd_vel"


def cmd_vel_output(config: RobotConfig) -> Output:
    """``cmd/twist`` as the ``cmd_vel`` the service subscribes to, for ``icefloe record --ros2``: the
    robot's drive commands in the recording as a ROS 2 node would have sent them."""
    types = ros2.typestore(config.ros2.distro).types
    return Output(keys.TWIST, CMD_VEL, TWIST, lambda twist: twist_message(twist, types))


def inputs(config: RobotConfig) -> list[Input]:
    """The ROS 2 topics a replay turns back into icefloe's keys (the others are replayed as raw bytes)."""
    return [Input("odom", ODOMETRY, keys.ODOM_POSE, Odometry.pose),
            Input(CMD_VEL, TWIST, keys.TWIST, twist_of)]


def twist_message(twist: m.Twist, types: Any) -> Any:
    """``cmd/twist`` as a geometry_msgs/msg/Twist (the reverse of `twist_command`): ``v`` -> ``linear.x``,
    ``w`` -> ``angular.z``. ``types``: the distribution's rosbags types."""
    vector3 = types["geometry_msgs/msg/Vector3"]
    return types[TWIST](linear=vector3(x=twist.v, y=0.0, z=0.0), angular=vector3(x=0.0, y=0.0, z=twist.w))


def twist_of(twist: Any) -> m.Twist:
    """A geometry_msgs/msg/Twist as a ``cmd/twist`` of no sender: replayed, hwbridge orders it by
    when it arrives, as a plain put. Raises ValueError for a speed that is not a finite number."""
    v, w = float(twist.linear.x), float(twist.angular.z)
    if not (math.isfinite(v) and math.isfinite(w)):
        raise ValueError(f"linear.x {v} or angular.z {w} is not a finite number")
    return m.Twist(v=v, w=w)


def twist_command(payload: bytes, attachment: bytes | None, distro: ros2.Distro) -> m.Twist:
    """A geometry_msgs/msg/Twist sample (CDR) as icefloe's ``cmd/twist``: ``linear.x`` -> ``v``,
    ``angular.z`` -> ``w`` (a differential drive has no other motion). The attachment orders it:
    ``sender`` is the ROS 2 publisher's GID, ``seq`` and ``stamp`` its sequence number and source
    timestamp, so a stop on the bus wins over every ROS 2 command issued before it.
    Raises ValueError naming what is wrong."""
    twist = twist_of(ros2.from_cdr(payload, TWIST, distro))
    v, w = twist.v, twist.w
    if attachment is None:
        return twist  # a plain Zenoh put: ordered by when the robot's router saw it
    meta = ros2.Attachment.decode(attachment)
    if meta.seq < 0 or meta.stamp <= 0:
        raise ValueError(f"attachment's sequence number {meta.seq} or timestamp {meta.stamp} is negative or zero")
    return m.Twist(v=v, w=w, sender=f"ros2:{meta.gid.hex()}", seq=meta.seq, stamp=meta.stamp)
