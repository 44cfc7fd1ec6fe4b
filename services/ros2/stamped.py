"""What every ROS 2 message here is built from: a header (stamp and frame) and a heading as a
quaternion, made with the rosbags classes of one distribution."""

from __future__ import annotations

import math
from typing import Any

from icefloe import ros2


class Builder:
    """The message classes of one distribution (rosbags' typestore), and the parts every message shares."""

    def __init__(self, distro: ros2.Distro) -> None:
        self.distro = distro
        self.t = ros2.typestore(distro).types

    def time(self, stamp: int) -> Any:
        """ns since the epoch as builtin_interfaces/msg/Time (sec, nanosec)."""
        sec, nanosec = divmod(stamp, 1_000_000_000)
        return self.t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)

    def header(self, stamp: int, frame: str) -> Any:
        return self.t["std_msgs/msg/Header"](stamp=self.time(stamp), frame_id=frame)

    def heading(self, theta: float) -> Any:
        """A turn of ``theta`` rad about z (counter-clockwise, seen from above) as a unit quaternion."""
        return self.t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(theta / 2), w=math.cos(theta / 2))

    def rotation(self, rodrigues: list[float]) -> Any:
        """OpenCV's rotation vector (axis times angle, rad) as a unit quaternion."""
        angle = math.sqrt(sum(v * v for v in rodrigues))
        if angle < 1e-12:
            return self.t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
        s = math.sin(angle / 2) / angle
        x, y, z = (v * s for v in rodrigues)
        return self.t["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=math.cos(angle / 2))

    def point(self, x: float, y: float, z: float = 0.0) -> Any:
        return self.t["geometry_msgs/msg/Point"](x=x, y=y, z=z)

    def vector(self, x: float, y: float, z: float = 0.0) -> Any:
        return self.t["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)

    def pose(self, x: float, y: float, theta: float) -> Any:
        """A pose on the floor (z = 0)."""
        return self.t["geometry_msgs/msg/Pose"](position=self.point(x, y), orientation=self.heading(theta))
