"""The robot's state as ROS 2 messages: ``tf``, ``joint_states``, ``battery_state``, the poses
in the map frame (``pose``, ``external_pose``) and ``map``. Each class turns one icefloe message
into one rosbags message object; a message it cannot turn raises ValueError naming the field."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from icefloe import ros2
from icefloe.schemas import messages as m

from .stamped import Builder

TF = "tf2_msgs/msg/TFMessage"
JOINT_STATE = "sensor_msgs/msg/JointState"
BATTERY_STATE = "sensor_msgs/msg/BatteryState"
POSE_WITH_COVARIANCE = "geometry_msgs/msg/PoseWithCovarianceStamped"
OCCUPANCY_GRID = "nav_msgs/msg/OccupancyGrid"

WHEEL_JOINTS = ("left_wheel_joint", "right_wheel_joint")
"""The joints of ``joint_states``, as a differential drive's URDF names them."""


class Transform:
    """``odom/pose`` as ``tf``: one transform, ``odom_frame`` -> ``base_frame`` (what robot_state_publisher
    and RViz need beside ``odom``)."""

    def __init__(self, distro: ros2.Distro, parent: str, child: str) -> None:
        self.b, self.parent, self.child = Builder(distro), parent, child

    def message(self, pose: m.Pose) -> Any:
        t = self.b.t
        moved = t["geometry_msgs/msg/Transform"](translation=self.b.vector(pose.x, pose.y),
                                                 rotation=self.b.heading(pose.theta))
        stamped = t["geometry_msgs/msg/TransformStamped"](header=self.b.header(pose.stamp, self.parent),
                                                          child_frame_id=self.child, transform=moved)
        return t[TF](transforms=[stamped])


class WheelJoints:
    """``hw/wheels`` as ``joint_states``: each wheel's angle from its encoder count (rad, unwrapped)
    and its turn rate from its rim speed (rad/s = m/s over the wheel's radius). Positive turns roll
    the robot forward, on both wheels (a joint axis of +y for both, as differential drives' URDFs
    have it). No effort is measured: ``effort`` is empty, as the message allows."""

    def __init__(self, distro: ros2.Distro, wheel_diameter: float, ticks_per_rev: int) -> None:
        self.b = Builder(distro)
        self.rad_per_tick = 2 * math.pi / ticks_per_rev
        self.radius = wheel_diameter / 2

    def message(self, wheels: m.Wheels) -> Any:
        return self.b.t[JOINT_STATE](
            header=self.b.header(wheels.stamp, ""),  # joint states name no frame
            name=list(WHEEL_JOINTS),
            position=np.array([wheels.ticks_left, wheels.ticks_right], dtype=np.float64) * self.rad_per_tick,
            velocity=np.array([wheels.speed_left, wheels.speed_right], dtype=np.float64) / self.radius,
            effort=np.zeros(0, dtype=np.float64))


class Battery:
    """``power/battery`` as ``battery_state``: voltage, and current with ROS 2's sign (negative while
    discharging; icefloe's is the current drawn). What the board does not measure is NaN, as the
    message says to (temperature, charge, capacity, percentage); ``low`` and ``critical`` have no
    field in BatteryState: they stay on ``power/battery``."""

    def __init__(self, distro: ros2.Distro) -> None:
        self.b = Builder(distro)

    def message(self, battery: m.Battery) -> Any:
        t, nan = self.b.t, math.nan
        state = t[BATTERY_STATE]
        status = state.POWER_SUPPLY_STATUS_DISCHARGING if battery.current > 0 else state.POWER_SUPPLY_STATUS_UNKNOWN
        return state(header=self.b.header(battery.stamp, ""), voltage=battery.voltage, temperature=nan,
                     current=-battery.current, charge=nan, capacity=nan, design_capacity=nan, percentage=nan,
                     power_supply_status=status, power_supply_health=state.POWER_SUPPLY_HEALTH_UNKNOWN,
                     power_supply_technology=state.POWER_SUPPLY_TECHNOLOGY_UNKNOWN, present=True,
                     cell_voltage=np.zeros(0, dtype=np.float32), cell_temperature=np.zeros(0, dtype=np.float32),
                     location="", serial_number="")


class MapPose:
    """``loc/pose`` (the localizer's) or ``extloc/pose`` (the lab's overhead camera's) as
    PoseWithCovarianceStamped in the map frame. The 3x3 covariance of (x, y, theta) goes into the
    6x6 of (x, y, z, roll, pitch, yaw): rows and columns 0, 1 and 5; the rest is 0 (a pose on the floor)."""

    SLOTS = (0, 1, 5)

    def __init__(self, distro: ros2.Distro, frame: str) -> None:
        self.b, self.frame = Builder(distro), frame

    def message(self, pose: m.PoseEstimate | m.ExternalPose) -> Any:
        if len(pose.covariance) != 9:
            raise ValueError(f"covariance: {len(pose.covariance)} numbers, not 9 (3x3 of x, y, theta)")
        six = np.zeros((6, 6), dtype=np.float64)
        six[np.ix_(self.SLOTS, self.SLOTS)] = np.asarray(pose.covariance, dtype=np.float64).reshape(3, 3)
        t = self.b.t
        with_covariance = t["geometry_msgs/msg/PoseWithCovariance"](pose=self.b.pose(pose.x, pose.y, pose.theta),
                                                                    covariance=six.ravel())
        return t[POSE_WITH_COVARIANCE](header=self.b.header(pose.stamp, self.frame), pose=with_covariance)


class Map:
    """The grid service's ``map/grid`` answer as ``map``: the same cells in the same order (row 0 at
    the origin's y, row-major), occupied 100, free 0 (ROS 2's percentages; icefloe's grid knows no
    unknown cell, -1)."""

    def __init__(self, distro: ros2.Distro, frame: str) -> None:
        self.b, self.frame = Builder(distro), frame

    def message(self, grid: m.OccupancyGrid) -> Any:
        if len(grid.cells) != grid.width * grid.height:
            raise ValueError(f"cells: {len(grid.cells)} bytes, not width x height = {grid.width * grid.height}")
        t = self.b.t
        info = t["nav_msgs/msg/MapMetaData"](map_load_time=self.b.time(grid.stamp), resolution=grid.resolution,
                                             width=grid.width, height=grid.height,
                                             origin=self.b.pose(grid.origin_x, grid.origin_y, 0.0))
        cells = np.frombuffer(grid.cells, dtype=np.uint8)
        data = np.where(cells != 0, 100, 0).astype(np.int8)
        return t[OCCUPANCY_GRID](header=self.b.header(grid.stamp, self.frame), info=info, data=data)
