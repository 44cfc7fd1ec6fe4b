"""The key table: which key expression carries which message.

Every key is ``icefloe/<robot>/<name>``, where ``<robot>`` is the robot config's
``name`` ("sim" for the simulated robot) and ``<name>`` is from the table below.

    >>> key("penguin1", TWIST)
    'icefloe/penguin1/cmd/twist'
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from . import messages as m

PREFIX = "icefloe"


@dataclass(frozen=True)
class Topic:
    """One row of the key table."""

    name: str
    """Key under the robot, e.g. "cmd/twist"."""
    type: type[m.Message]
    """The message the key carries (for a queryable: what the query sends)."""
    kind: Literal["in", "out", "query"]
    """in: commands to the robot; out: state from the robot; query: a queryable."""
    reply: type[m.Message] | None = None
    """For a queryable: the message of its answer."""
    urgent: bool = False
    """Sent at Zenoh's real-time priority, without batching: overtakes other traffic in
    every queue on the way (``cmd/stop``)."""
    read_only: bool = False
    """For a queryable: asking it changes nothing on the robot, so anyone who may watch the
    robot (the read-only ``guest`` too) may ask it. Every other queryable is a command."""

    @property
    def command(self) -> bool:
        """Does a message on this key make the robot do something (an ``in`` key, or a queryable
        that is not `read_only`)? Only the robot's owner may send one (docs/lab.md)."""
        return self.kind == "in" or (self.kind == "query" and not self.read_only)


TWIST = Topic("cmd/twist", m.Twist, "in")
WHEELS_CMD = Topic("cmd/wheels", m.WheelSpeeds, "in")
STOP = Topic("cmd/stop", m.Stop, "in", urgent=True)
MOTION = Topic("cmd/motion", m.Motion, "query", reply=m.MotionDone)
CAR = Topic("cmd/car", m.CarDrive, "in")
"""Drive as a car: speed and steering angle (the virtual car of ``[car]``, docs/motion-models.md)."""
LEDS = Topic("io/leds", m.Led, "in")
LEDARRAY = Topic("io/ledarray", m.LedArray, "in")
OLED_TEXT = Topic("oled/text", m.OledText, "in")
OLED_SCREEN = Topic("oled/screen", m.OledScreen, "in")
BOARD_TEXT = Topic("io/text", m.OledText, "in")
"""Raw user text for the board's own display (PenguinPi firmware user screen), via hwbridge."""
BOARD_SCREEN = Topic("io/screen", m.OledScreen, "in")
"""Select the board's own display screen (PenguinPi HAT_SET_SCREEN), via hwbridge."""
HALT = Topic("cmd/halt", m.Halt, "query", reply=m.Wheels)
"""Stop the wheels and answer once hwbridge has confirmed it: the board at zero duty and, with
``rest`` (the default), the wheels at rest (the power service asks before power-off)."""
LAB_STOP = Topic("lab/stop", m.LabStop, "query", reply=m.LabStopDone)
"""The lab's emergency stop: stop, hold stopped, or release a hold (`LabStop`). Only the lab's TA
account may ask it; a robot's owner may not (deploy/zenoh/acl/owner.json5, docs/lab.md)."""
RELEASE = Topic("cmd/release", m.Release, "query", reply=m.Hold)
"""The owner's end of a TA's hold, where the TA allowed it (`LabStop.owner_may_release`)."""

WHEELS = Topic("hw/wheels", m.Wheels, "out")
LOOP = Topic("hw/loop", m.LoopStats, "out")
HW_BATTERY = Topic("hw/battery", m.BatteryReading, "out")
HOLD = Topic("hw/hold", m.Hold, "out")
"""Whether the lab's TA holds the robot stopped (hwbridge, at each change and once a second)."""
BUTTONS = Topic("io/buttons", m.Buttons, "out")
DIP = Topic("io/dip", m.Dip, "out")
ODOM_POSE = Topic("odom/pose", m.Pose, "out")
CAR_STATE = Topic("car/state", m.CarState, "out")
"""The virtual car's steering and bicycle-model pose, from hwbridge (docs/motion-models.md)."""
LOC_POSE = Topic("loc/pose", m.PoseEstimate, "out")
IMAGE = Topic("camera/image", m.Image, "out")
LANDMARKS = Topic("camera/landmarks", m.Landmarks, "out")
BATTERY = Topic("power/battery", m.Battery, "out")
SHUTDOWN = Topic("power/shutdown", m.ShutdownNotice, "out")
OLED_FRAME = Topic("oled/frame", m.OledFrame, "out")
LOG = Topic("log", m.Log, "out")
CLOCK = Topic("clock", m.Clock, "out")
"""The time of a recording being replayed (published by ``icefloe replay --clock`` only)."""
EXTLOC_POSE = Topic("extloc/pose", m.ExternalPose, "out")
"""The robot's pose from the lab's overhead camera; published by the lab's localizer only (docs/extloc.md)."""
TRUTH = Topic("sim/truth", m.Truth, "out")
MAP_LANDMARKS = Topic("map/landmarks", m.LandmarkMap, "out")
"""The landmark map made with a known pose (services/mapper, or your own map maker)."""
SLAM_POSE = Topic("slam/pose", m.PoseEstimate, "out")
"""SLAM's pose of the robot, in SLAM's frame (services/slam, or your own)."""
SLAM_MAP = Topic("slam/map", m.LandmarkMap, "out")
"""SLAM's landmark map, in SLAM's frame (services/slam, or your own)."""
SIM_GPIO = Topic("sim/gpio", m.GpioLevel, "out")
"""Simulated GPIO line levels; each line's driver publishes it (see `GpioLevel`)."""
SIM_CONTROL = Topic("sim/control", m.SimControl, "query", reply=m.SimState)
"""The simulator's test handles (see `SimControl`)."""

ODOM_RESET = Topic("odom/reset", m.PoseReset, "query", reply=m.Pose)
SNAPSHOT = Topic("camera/snapshot", m.Stop, "query", reply=m.Image, read_only=True)
FRAMES = Topic("camera/frames", m.Image, "out")
"""Every captured frame as a JPEG of ``camera.image_width`` x ``image_height`` (what the web API's
``/camera/get`` streams), published only while something subscribes to it: it costs nothing
when nobody watches (subscribe to ``camera/image`` for a few frames a second)."""
FRAME = Topic("camera/frame", m.Stop, "query", reply=m.Image, read_only=True)
"""The latest frame as a JPEG of ``camera.image_width`` x ``image_height`` (web API ``/camera/frame``)."""
CAMERA_INFO = Topic("camera/info", m.Stop, "query", reply=m.CameraInfo, read_only=True)
"""The intrinsics of the ``image_width`` x ``image_height`` images (`CameraInfo`)."""
INFO = Topic("info", m.Stop, "query", reply=m.RobotInfo, read_only=True)
SHUTDOWN_REQUEST = Topic("power/request", m.ShutdownRequest, "query", reply=m.ShutdownNotice)
MAP_GRID = Topic("map/grid", m.GridRequest, "query", reply=m.OccupancyGrid, read_only=True)
"""The world's occupancy grid (services/grid), inflated on request."""
PLAN = Topic("nav/plan", m.PlanRequest, "query", reply=m.Plan)
"""A path from start to goal on the grid (services/planner, or your own planner)."""
NAV_PATH = Topic("nav/path", m.NavPath, "in")
"""A path for the follower to drive (services/follower, or your own)."""
NAV_STATUS = Topic("nav/status", m.FollowStatus, "out")
JUDGE_STATE = Topic("judge/state", m.JudgeState, "out")
"""The lap judge's lap in progress: time, penalties, latest events (services/judge, docs/judge.md)."""
JUDGE_LAP = Topic("judge/lap", m.JudgeLap, "out")
"""One lap's result at its end (services/judge)."""

TABLE: dict[str, Topic] = {
    t.name: t
    for t in (
        TWIST, WHEELS_CMD, CAR, STOP, MOTION, HALT, LAB_STOP, RELEASE, LEDS, LEDARRAY, OLED_TEXT, OLED_SCREEN,
        BOARD_TEXT, BOARD_SCREEN,
        WHEELS, LOOP, HW_BATTERY, HOLD, BUTTONS, DIP, ODOM_POSE, CAR_STATE, LOC_POSE, IMAGE, LANDMARKS,
        BATTERY, SHUTDOWN, OLED_FRAME, LOG, CLOCK, EXTLOC_POSE, TRUTH, SIM_GPIO,
        ODOM_RESET, SNAPSHOT, INFO, SHUTDOWN_REQUEST, SIM_CONTROL, FRAMES, FRAME, CAMERA_INFO,
        MAP_GRID, PLAN, NAV_PATH, NAV_STATUS,
        MAP_LANDMARKS, SLAM_POSE, SLAM_MAP, JUDGE_STATE, JUDGE_LAP,
    )
}  # fmt: skip


READ_ONLY_QUERIES = [t for t in TABLE.values() if t.kind == "query" and t.read_only]
"""The queryables a guest may ask (deploy/zenoh/acl.json5 is filled in from this list)."""


def key(robot: str, topic: Topic | str) -> str:
    """The full key expression of a topic on a robot."""
    name = topic.name if isinstance(topic, Topic) else topic
    return f"{PREFIX}/{robot}/{name}"


def alive_key(robot: str, service: str) -> str:
    """The liveliness token a running service holds: ``icefloe/<robot>/alive/<service>``."""
    return f"{PREFIX}/{robot}/alive/{service}"


def alive_of(key_expr: str) -> tuple[str, str] | None:
    """``"icefloe/sim/alive/hwbridge"`` -> ``("sim", "hwbridge")``; None for anything else,
    a wildcard token (``icefloe/*/alive/x``) included: it names no robot and no service."""
    parts = str(key_expr).split("/")
    if len(parts) != 4 or parts[0] != PREFIX or parts[2] != "alive" or not is_concrete(key_expr):
        return None
    return (parts[1], parts[3]) if parts[1] and parts[3] else None


def is_concrete(key_expr: str) -> bool:
    """Does ``key_expr`` name one key only (no ``*``, ``**`` or ``$*`` wildcard)?"""
    return "*" not in key_expr


def split(key_expr: str) -> tuple[str, str]:
    """``"icefloe/sim/cmd/twist"`` -> ``("sim", "cmd/twist")``.

    Raises ValueError for a key outside the icefloe namespace.
    """
    parts = str(key_expr).split("/", 2)
    if len(parts) != 3 or parts[0] != PREFIX or not parts[1] or not parts[2]:
        raise ValueError(f"{key_expr!r} is not an icefloe key (icefloe/<robot>/<name>)")
    return parts[1], parts[2]


def topic_of(key_expr: str) -> Topic | None:
    """The table row for a full key expression, or None if the key is not in the table."""
    try:
        return TABLE.get(split(key_expr)[1])
    except ValueError:
        return None


def all_but_frames(robot: str) -> list[str]:
    """Key expressions that reach every key of ``robot`` but ``camera/frames``.

    A subscriber whose key expression reaches ``camera/frames`` turns the camera's full-rate
    JPEG stream on (~13 frames/s, ~300 KB/s: Zenoh's matching status), and Zenoh has no
    "all but" in key expressions. So: keys of one chunk, of three or more, each namespace of
    the key table but ``camera`` (``hw/*``, ``odom/*``, ...), and ``camera``'s other keys one by
    one. Not reached: a key of two chunks in a namespace the key table does not have
    (``icefloe/<robot>/my/thing``): name it, or follow ``icefloe/<robot>/**``. ``robot`` may be ``*``.
    """
    base = f"{PREFIX}/{robot}"
    two = [t.name for t in TABLE.values() if t.name.count("/") == 1 and t.kind != "query"]
    namespaces = sorted({name.split("/")[0] for name in two} - {"camera"})
    camera = sorted(n for n in two if n.startswith("camera/") and n != FRAMES.name)
    return [base, f"{base}/*", *(f"{base}/{ns}/*" for ns in namespaces), *(f"{base}/{n}" for n in camera),
            f"{base}/*/*/*/**"]


def without_frames(key_expr: str) -> list[str]:
    """``key_expr`` as key expressions that leave ``camera/frames`` out when it is every key of a
    robot (``icefloe/<robot>/**``, ``<robot>`` may be ``*``: `all_but_frames`); any other as it is
    (one that names ``camera/frames`` or ``camera/*`` asks for the frames)."""
    parts = key_expr.split("/")
    if len(parts) == 3 and parts[0] == PREFIX and parts[2] == "**" and "**" not in parts[1]:
        return all_but_frames(parts[1])
    return [key_expr]
