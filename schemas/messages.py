"""Every message on the icefloe bus, as msgspec Structs.

This file is the contract. A student writing a service in another language reads
it (or the JSON Schemas generated from it in ``schemas/json/``) and nothing else.

Conventions, the same for every message:

* Payloads are MessagePack **maps** keyed by the field names below, Zenoh
  encoding ``application/msgpack``. Inputs (``cmd/...``, ``io/leds``, ``oled/text``
  and the queryables) also accept ``application/json`` with the same fields.
* SI units everywhere: m, s, rad, m/s, rad/s, V, A.
* ``stamp`` is integer nanoseconds since the Unix epoch (``time.time_ns()``).
* ``theta`` and bearings are counter-clockwise positive, wrapped to (-pi, pi].
* Unknown fields are rejected, and so are non-finite floats (NaN, inf): a bad
  message is dropped with one log line naming the key and the field.

Which key carries which message is in ``keys.py``.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import msgspec


class Message(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Base of every bus message: immutable, keyword-only, no unknown fields, finite floats."""

    def __post_init__(self) -> None:
        # msgspec accepts NaN and inf for `float`; on a robot they are always a bug.
        for name in self.__struct_fields__:
            value = getattr(self, name)
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"field `{name}` must be a finite number, got {value}")


# --------------------------------------------------------------------------- commands (in)


class Command(Message, kw_only=True):
    """Base of the commands that move or stop the wheels: who issued it, in which order, when.

    All three fields are optional (a student's ``{"v": 0.1, "w": 0}`` still drives),
    but only with them can hwbridge put a stop and the motion commands around it in
    the order they were issued, whatever priority or path each took on the bus (see
    docs/hwbridge.md, "Which command wins"). The client library, the web API and the
    examples fill them in.
    """

    sender: Annotated[str, msgspec.Meta(max_length=64)] = ""
    """Who issued it: any id unique to the sending program, e.g. its Zenoh session id ("" = not given)."""
    seq: Annotated[int, msgspec.Meta(ge=0)] = 0
    """The sender's number for this command: each command or stop it issues, on any key, has
    a larger one than the one before (0 = not given)."""
    stamp: Annotated[int, msgspec.Meta(ge=0)] = 0
    """When the sender issued it, ns since the epoch on the sender's clock; that clock may be
    off the robot's, but must not jump backwards (0 = not given; needs ``sender``)."""


class Twist(Command):
    """``cmd/twist``: drive the robot's body. hwbridge clamps to the configured limits."""

    v: float
    """Forward speed, m/s (positive forward)."""
    w: float
    """Turn rate, rad/s (counter-clockwise positive)."""


class WheelSpeeds(Command):
    """``cmd/wheels``: drive each wheel directly, rim speeds in m/s (positive forward)."""

    left: float
    right: float


class CarDrive(Command):
    """``cmd/car``: drive the robot as a car (the virtual Ackermann-steered car of the robot
    config's ``[car]``, docs/motion-models.md): a forward speed and a steering angle.

    The steering angle, not the curvature: it is what a car's driver sets and what the bicycle
    model of the textbooks (and the Robotics Toolbox's ``Bicycle``) takes, and the car's limits
    are on it: its largest angle (``car.max_steer``) and how fast it turns (``car.steer_rate``).
    The path's curvature is tan(steer) / ``car.wheelbase``. hwbridge turns the steering towards
    ``steer`` at the steering rate, clips it to the largest angle and slows the car (its turn
    kept) when the outer wheel would pass ``hwbridge.max_wheel_speed``, each with a log line;
    ``car/state`` says what it applies.
    """

    v: float
    """Forward speed of the car's rear axle, m/s (positive: the car's forward)."""
    steer: float
    """Steering angle of the front wheel (the bicycle model's one wheel), rad, positive to the
    left (counter-clockwise); clipped to +-``car.max_steer``."""


class Stop(Command):
    """``cmd/stop``: stop now. An empty map (or an empty payload) will do.

    The stop latches: the wheels stay stopped until a twist, wheels, car or motion
    command issued after it.
    """


class Halt(Stop):
    """``cmd/halt`` query: stop now, and answer (with `Wheels`) once hwbridge has confirmed it."""

    rest: bool = True
    """True: answer once both wheels are also at rest; False: as soon as the board runs
    zero duty with its controller cleared."""


class LabStop(Command):
    """``lab/stop`` query: the lab's emergency stop, the TA's alone (docs/lab.md): stop the wheels
    now, as ``cmd/stop`` does, and answer (`LabStopDone`) once the board has confirmed it, or
    within ``timeout`` that it has not.

    ``action``:

    * ``"stop"``: only that; the next motion command drives again.
    * ``"hold"``: stop, and refuse every motion command (``cmd/twist``, ``cmd/wheels``,
      ``cmd/motion``) until the hold is released: a program that keeps driving cannot drive.
    * ``"release"``: end a hold. The robot stays stopped; a motion command issued after the
      release drives again (none issued before it does).
    """

    action: Literal["stop", "hold", "release"] = "stop"
    owner_may_release: bool = False
    """``"hold"``: the robot's owner may release the hold too (``cmd/release``); else only the TA."""
    reason: Annotated[str, msgspec.Meta(max_length=60)] = ""
    """What the TA says, shown on the robot's screen, its web page and its log ("" = nothing)."""
    timeout: Annotated[float, msgspec.Meta(gt=0, le=10)] = 1.0
    """Answer by then, s: confirmed, or not confirmed and why."""


class LabStopDone(Message):
    """Answer to ``lab/stop``: what the robot did."""

    stamp: int
    confirmed: bool
    """The board confirmed the stop this request latched (zero duty, controller cleared) within
    the request's ``timeout``."""
    held: bool
    """The robot is held stopped now (`Hold`)."""
    detail: str = ""
    """Why it is not confirmed; else "" or a note ("was not held": a release that changed nothing)."""


class Release(Command):
    """``cmd/release`` query: the robot's owner ends a hold of the lab's TA, if the TA allowed it
    (`LabStop.owner_may_release`); answered with `Hold`, or an error saying only the TA may."""


class Motion(Command):
    """``cmd/motion`` query: run the wheels at fixed speeds for a time, then stop.

    Like the PenguinPi web API's ``/robot/set/velocity?value=L,R&time=T&accel=A``:
    speeds ramp up over ``accel`` seconds, hold, ramp down over ``accel`` seconds.
    The query is answered with a `MotionDone` when the motion has ended and the
    board has confirmed the stop.
    """

    left: float
    """Left wheel rim speed, m/s."""
    right: float
    """Right wheel rim speed, m/s."""
    duration: float
    """Time at full speed plus one ramp, s (> 0, and > 2 * accel)."""
    accel: float = 0.0
    """Length of each ramp, s (0 = step)."""


class MotionDone(Message):
    """Answer to ``cmd/motion``: how the motion ended."""

    stamp: int
    completed: bool
    """False when a stop command, the deadman or another motion cut it short, or when it was
    refused (issued before a stop, or older than the deadman)."""
    reason: str = ""


class Led(Message):
    """``io/leds``: set or pulse one LED on the board.

    PenguinPi LED numbers: 1 red, 2..4 the yellow LEDs 2..4 (LED 4 is also the
    shutdown daemon's "alive" lamp on the real board).
    """

    led: int
    on: bool = True
    pulse: float = 0.0
    """If > 0: light for this many seconds (<= 0.255 on the PenguinPi), then off."""


class LedArray(Message):
    """``io/ledarray``: the 16-LED array of the PenguinPi HAT, bit n = LED n (bit 0 bottom right)."""

    mask: int


class OledText(Message):
    """``oled/text``: text for the user screen, a tiny terminal.

    ``\\n`` starts a new line, ``\\f`` clears the screen, long lines wrap.
    """

    text: str


class OledScreen(Message):
    """``oled/screen``: select the screen shown (index into the screen list of the oled service)."""

    index: int


class PoseReset(Message):
    """``odom/reset`` query payload (optional): the pose to reset to. Empty = origin."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0


class ShutdownRequest(Message):
    """``power/request`` query: ask the robot to power off (authorised users only)."""

    reason: str = "requested on the bus"


# --------------------------------------------------------------------------- hardware (out)


class Wheels(Message):
    """``hw/wheels``: encoder state, published by hwbridge (100 Hz by default)."""

    stamp: int
    """Time of the encoder sample, ns since the epoch."""
    ticks_left: int
    """Left encoder count, unwrapped (never wraps; 384 counts per wheel turn on the PenguinPi)."""
    ticks_right: int
    speed_left: float
    """Measured left rim speed, m/s."""
    speed_right: float
    target_left: float = 0.0
    """Commanded left rim speed, m/s (after clamping, ramps and the deadman)."""
    target_right: float = 0.0


class LoopStats(Message):
    """``hw/loop``: timing of hwbridge's real-time cycle over the last reporting interval (1 Hz)."""

    stamp: int
    rate: float
    """Cycles per second achieved, Hz (``hwbridge.rest_rate_hz`` while the cycle rests: the robot stands)."""
    period_mean: float
    """Mean period between cycle starts, s."""
    period_max: float
    latency_p50: float
    """Wake-up latency (actual start minus deadline), s: median."""
    latency_p99: float
    latency_p999: float
    latency_max: float
    overruns: int
    """Cycles that missed their deadline, since start."""
    cycles: int
    """Cycles run since start."""
    board: str = ""
    """Which board backend, e.g. "penguinpi" or "icoboard-v2"."""
    link_errors: int = 0
    """Corrupt, lost or unmatched frames on the board link, since start."""
    link_rate: float = 0.0
    """Wheel exchanges with the board completed per second, Hz (PenguinPi: MULTI_SET_VEL_GET_ENC
    replies, limited by 115200 baud; icoBoard: SPI frames, one per cycle)."""
    crc_errors: int = 0
    """Frames with a bad CRC, since start."""
    timeouts: int = 0
    """Requests the board did not answer in time, since start."""
    unmatched: int = 0
    """Good frames that answered no open request (duplicates, replies nobody asked for), since start."""
    garbage_bytes: int = 0
    """Bytes that were neither a frame nor board text, since start."""
    board_errors: int = 0
    """Errors the board reported itself (PenguinPi ``ERR:`` lines, icoBoard REJECTED), since start."""
    stalled_reads: int = 0
    """Reads of the shared memory between hwbridge's two processes that found the other one in the
    middle of a write on every try and were put off, since start: the bus process reading the cycle's
    state (it tries again after a back-off) plus the cycle reading the commands (that period stops
    the wheels). Above 0, one of the two was descheduled mid-write: the machine is short of CPU
    for them (no SCHED_FIFO, or many robots on one machine)."""
    late: int = 0
    """Replies that came after their request had timed out: counted, never used, since start."""
    commands_dropped: int = 0
    """Motion commands not applied because they were issued before a stop, were older than the
    deadman or were overtaken by a newer one from the same sender, since start."""
    realtime_priority: int = 0
    """``SCHED_FIFO`` priority the cycle runs at (``hwbridge.priority`` when the OS granted it);
    0: normal scheduling, the OS refused real time (hwbridge's log says why at start)."""
    memory_locked: bool = False
    """The cycle's memory is locked in RAM (``mlockall`` granted), so it is never paged out."""


class Hold(Message):
    """``hw/hold``: whether the lab's TA holds the robot stopped (``lab/stop``), published by
    hwbridge at each change and once a second. While ``held``, hwbridge refuses every motion
    command; the robot's screen and web page say so."""

    stamp: int
    held: bool
    since: int = 0
    """When the hold began, ns since the Unix epoch (0 = not held)."""
    reason: str = ""
    """What the TA said (`LabStop.reason`)."""
    owner_may_release: bool = False
    """The robot's owner may release it (``cmd/release``); else only the TA (``lab/stop``)."""


class BatteryReading(Message):
    """``hw/battery``: raw battery reading from the board (the power service filters it)."""

    stamp: int
    voltage: float
    """V."""
    current: float
    """A."""


class Buttons(Message):
    """``io/buttons``: a button was pressed (or released). Sent once per event.

    Who sends what: hwbridge sends presses of the PenguinPi HAT's S4 (3), which its
    firmware only counts (no releases; S1..S3 act on the board itself); the power
    service sends presses and releases of the shutdown button (10), which it reads
    as a GPIO line (held for ``power.button_hold_s`` it shuts the robot down).
    """

    stamp: int
    button: int
    """0..3 for the PenguinPi HAT's S1..S4; 10 for the shutdown button."""
    presses: int = 1
    """Presses since the last message (the board may count several between two reads); 0 for a release."""
    event: Literal["press", "release"] = "press"


class Dip(Message):
    """``io/dip``: the DIP switch, published when it changes and once a second."""

    stamp: int
    value: int
    """0..15: SW1 = 8, SW2 = 4, SW3 = 2, SW4 = 1."""


# --------------------------------------------------------------------------- estimates (out)


class Pose(Message):
    """``odom/pose``: dead-reckoned pose of the robot in the odometry frame."""

    stamp: int
    x: float
    """m."""
    y: float
    """m."""
    theta: float
    """rad, counter-clockwise positive, in (-pi, pi]."""
    v: float = 0.0
    """Forward speed, m/s."""
    w: float = 0.0
    """Turn rate, rad/s."""


class CarState(Message):
    """``car/state``: the virtual car as hwbridge drives it (docs/motion-models.md): its steering
    after the rate limit, and the bicycle model's pose of its rear axle, integrated from what was
    applied (starting at 0, 0, 0 where hwbridge started; no wheel slip, no wheel lag), to compare
    with ``odom/pose`` and the simulator's ``sim/truth``. Published at ``car.state_rate_hz``
    while the car moves or steers, once a second otherwise."""

    stamp: int
    v: float
    """Forward speed applied, m/s: the command's, slowed for the wheels' limit; 0 after a stop,
    the deadman, or another kind of command."""
    steer: float
    """Steering angle now, rad (left positive), after the rate limit."""
    steer_target: float
    """The angle it turns towards: the last ``cmd/car``'s, clipped to +-``car.max_steer``, rad."""
    x: float
    """Bicycle model: the rear axle's centre, m."""
    y: float
    """m."""
    theta: float
    """The car's heading, rad, counter-clockwise, in (-pi, pi]."""
    driving: bool = False
    """A ``cmd/car`` drives the wheels now (False: stopped, the deadman, or another command)."""


class PoseEstimate(Message):
    """``loc/pose``: the localizer's pose in the map frame, with its uncertainty."""

    stamp: int
    x: float
    y: float
    theta: float
    covariance: list[float]
    """3x3 covariance of (x, y, theta), row-major, 9 numbers (m^2, m*rad, rad^2)."""


class ExternalPose(Message):
    """``extloc/pose``: the robot's pose as the lab's overhead camera sees it (``services/extloc``),
    in the world frame (that of the world map, ``sim/truth`` and ``loc/pose``). Published only
    for a frame in which the robot's top marker was seen: no pose is repeated. Only the lab's
    localizer may publish it (docs/extloc.md)."""

    stamp: int
    """When the frame was taken, ns since the Unix epoch."""
    x: float
    """m."""
    y: float
    """m."""
    theta: float
    """rad, counter-clockwise from +x, in (-pi, pi]: where the robot's front points."""
    covariance: list[float]
    """3x3 covariance of (x, y, theta), row-major, 9 numbers (m^2, m*rad, rad^2)."""
    side_px: float = 0.0
    """Side of the robot's top marker in the picture, px: how well it was seen."""


class Truth(Message):
    """``sim/truth``: the simulated robot's true pose (simulator only)."""

    stamp: int
    x: float
    y: float
    theta: float
    collided: bool = False
    """True while the robot pushes against an obstacle of the world (it does not move into it)."""
    collisions: int = 0
    """Times the robot has run into an obstacle since the simulator started."""
    sim_time: float = 0.0
    """Simulated seconds since the simulator started, when this pose was true (its 1 kHz clock:
    exact where a busy machine makes it drop steps and the wall clock is not; 0 = not given). The
    lap judge times laps by it."""
    v: float = 0.0
    """True speed, m/s, forward (over the simulator's last 1 ms step)."""
    w: float = 0.0
    """True turn rate, rad/s, CCW."""


# --------------------------------------------------------------------------- maps of landmarks

MAX_MAP_LANDMARKS = 1000
"""Most landmarks in a `LandmarkMap` (ArUco's DICT_4X4_100 has 100)."""


class MapLandmark(Message):
    """One landmark of a `LandmarkMap`: its id and where the map puts it."""

    id: Annotated[int, msgspec.Meta(ge=0)]
    """ArUco id."""
    x: float
    """m, map frame."""
    y: float
    """m, map frame."""
    covariance: Annotated[list[float], msgspec.Meta(max_length=4)] = []
    """2x2 covariance of (x, y), row-major, 4 numbers, m^2 (empty = not known)."""


class LandmarkMap(Message, kw_only=True):
    """``map/landmarks`` (the map maker) and ``slam/map`` (SLAM): a map of landmarks, with how sure
    each one is; also the file format `icefloe score map` reads.

    ``map/landmarks`` is in the world frame of the pose it was made with; ``slam/map`` in SLAM's
    own frame (the robot's pose when SLAM started), which `icefloe score` aligns to the world's.
    """

    stamp: int = 0
    """ns since the Unix epoch: the last observation in the map."""
    landmarks: Annotated[list[MapLandmark], msgspec.Meta(max_length=MAX_MAP_LANDMARKS)]
    """By id, ascending."""


# --------------------------------------------------------------------------- planning

MAX_PATH_POINTS = 20_000
"""Most points in a path (`NavPath`, `Plan`): 400 m at 2 cm."""


class Waypoint(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One point of a path (`NavPath`, `Plan`), world frame. An object, not an ``[x, y]`` pair:
    Foxglove's JSON Schema reader takes arrays only of primitives or objects."""

    x: float
    """m, world frame."""
    y: float
    """m, world frame."""


def _check_points(points: list[Waypoint], field: str) -> None:
    if len(points) > MAX_PATH_POINTS:
        raise ValueError(f"field `{field}` has {len(points)} points, more than {MAX_PATH_POINTS}")
    for i, p in enumerate(points):
        if not (math.isfinite(p.x) and math.isfinite(p.y)):
            raise ValueError(f"field `{field}`: point {i} is not finite: ({p.x}, {p.y})")


class GridRequest(Message):
    """``map/grid`` query (optional payload): which occupancy grid of the world."""

    inflation: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.0
    """Grow the obstacles by this much, m (0 = as they stand; the robot's radius = the free space
    of its centre, as a planner wants it)."""


class OccupancyGrid(Message):
    """Answer to ``map/grid``: the world's obstacles as square cells (``icefloe/grid.py``).

    Cell (row, col) covers x in ``origin_x + [col, col + 1) * resolution``, y in ``origin_y +
    [row, row + 1) * resolution``; ``cells`` holds ``height`` rows of ``width`` bytes, row 0 first
    (the bottom row, y = origin_y): 1 = occupied, 0 = free.
    """

    stamp: int
    world: str
    """The world file's name."""
    resolution: float
    """Side of a cell, m."""
    origin_x: float
    """World x of the left edge of column 0, m."""
    origin_y: float
    """World y of the bottom edge of row 0, m."""
    width: int
    """Columns (cells along x)."""
    height: int
    """Rows (cells along y)."""
    inflation: float
    """The obstacles were grown by this much, m."""
    cells: bytes
    """width * height bytes, row-major, row 0 (bottom) first: 1 occupied, 0 free."""


class PlanRequest(Message):
    """``nav/plan`` query: a path from start to goal on the occupancy grid, world frame."""

    start_x: float
    """m."""
    start_y: float
    """m."""
    goal_x: float
    """m."""
    goal_y: float
    """m."""


class Plan(Message):
    """Answer to ``nav/plan``: the path, or why there is none."""

    stamp: int
    ok: bool
    """True: ``path`` goes from start to goal through free cells."""
    reason: str = ""
    """Why there is no path (``ok`` false): e.g. the goal is inside an obstacle, or walled off."""
    path: list[Waypoint] = []
    """Points from start to goal, world frame, m."""
    length: float = 0.0
    """Length of the path, m."""
    expanded: int = 0
    """Cells the search expanded."""
    seconds: float = 0.0
    """Time the planner took, s."""

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_points(self.path, "path")


class NavPath(Command):
    """``nav/path``: a path for the follower to drive, then stop at its end. An empty path, or a
    stop on ``cmd/stop``, ends the one being followed. Numbered like every command (`Command`):
    a path issued before a stop is not driven."""

    points: list[Waypoint]
    """Points to drive through, in order, world frame (the frame of ``loc/pose``), m."""
    speed: Annotated[float, msgspec.Meta(ge=0)] = 0.0
    """Forward speed, m/s (0 = the follower's configured speed)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_points(self.points, "points")


class FollowStatus(Message):
    """``nav/status``: what the path follower is doing (on every change and a few times a second)."""

    stamp: int
    state: Literal["idle", "following", "arrived", "stopped"]
    """"stopped": a stop, a new empty path or a lost pose ended the path before its end."""
    reason: str = ""
    """Why it stopped, or why a path was refused."""
    sender: str = ""
    """The path's sender (`Command.sender`)."""
    seq: int = 0
    """The path's number (`Command.seq`)."""
    points: int = 0
    """Points in the path."""
    cross_track: float = 0.0
    """Distance from the robot to the path now, m."""
    remaining: float = 0.0
    """Distance left along the path, m."""


# --------------------------------------------------------------------------- camera (out)


class Image(Message):
    """``camera/image``, ``camera/frames`` and the ``camera/snapshot`` and ``camera/frame`` query
    answers: one compressed frame."""

    stamp: int
    """When the frame was captured, ns since the epoch."""
    width: int
    height: int
    data: bytes
    """The compressed image."""
    format: Literal["jpeg"] = "jpeg"


class CameraInfo(Message):
    """``camera/info`` query answer (and ``GET /camera/info``): the intrinsics of the images the
    camera sends on ``camera/image``, ``camera/frames``, ``camera/frame`` and the web API's
    ``/camera/get`` (``camera.image_width`` x ``camera.image_height``): its calibration, made at
    the capture size, scaled to theirs. ``camera/snapshot`` is at the capture size (``capture_*``);
    multiply ``fx``, ``cx`` by ``capture_width / width`` (and y alike) for it."""

    width: int
    """Width of the images these intrinsics are for, px."""
    height: int
    """Height of the images these intrinsics are for, px."""
    fx: float
    """Focal length along x, px."""
    fy: float
    """Focal length along y, px."""
    cx: float
    """Principal point x, px (0 = the centre of the left pixel column)."""
    cy: float
    """Principal point y, px (0 = the centre of the top pixel row)."""
    camera_matrix: list[float]
    """The 3x3 matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] row by row (9 numbers, OpenCV's K)."""
    dist_coeffs: list[float]
    """OpenCV distortion coefficients (k1, k2, p1, p2, k3, ...); unitless, the same at any image size."""
    capture_width: int
    """Width of the frames the camera captures (and calibrates at), px."""
    capture_height: int
    """Height of the frames the camera captures, px."""
    source: str
    """Where the calibration came from: the calibration file's path, or "nominal" (``camera.focal_px``,
    no distortion: the camera was never calibrated)."""
    capture_latency_s: float = 0.0
    """Taken off every frame's stamp (and so off ``camera/landmarks``' and the images'), s: the time
    from a frame's exposure to its arrival, as the calibration measured it (0: none measured)."""


class Landmark(Message):
    """One detected ArUco marker, as seen from the robot."""

    id: int
    range: float
    """Distance from the robot's centre to the marker's centre, m."""
    bearing: float
    """Direction of the marker from the robot's heading, rad, counter-clockwise positive."""
    corners: list[float] = []
    """The four corners in pixels, x0, y0, x1, y1, ... (OpenCV order)."""
    position: list[float] = []
    """Marker centre in the camera frame (x right, y down, z forward), m."""
    rotation: list[float] = []
    """Marker orientation in the camera frame, Rodrigues vector, rad."""


class Landmarks(Message):
    """``camera/landmarks``: the markers detected in one frame."""

    stamp: int
    """Capture time of the frame."""
    landmarks: list[Landmark]


# --------------------------------------------------------------------------- power and screen


class Battery(Message):
    """``power/battery``: filtered battery state."""

    stamp: int
    voltage: float
    """V."""
    current: float
    """A."""
    state: Literal["ok", "low", "critical"]


class ShutdownNotice(Message):
    """``power/shutdown``: the robot is shutting down, and why."""

    stamp: int
    reason: str
    """e.g. "critical battery", "shutdown button", "board request", "requested on the bus"."""


class GpioLevel(Message):
    """``sim/gpio``: the level of one simulated Raspberry Pi GPIO line (simulator only).

    Whoever drives a line publishes it: the simulator drives the shutdown button
    (GPIO22) and the board's request line (GPIO10); the power service drives the
    acknowledge line (GPIO11). The lines are active low, so ``level = 0`` means
    "pressed" / "requested" / "Pi is shutting down".
    """

    stamp: int
    """Time of the change, ns since the epoch."""
    line: int
    """BCM line number."""
    level: int
    """0 (low) or 1 (high)."""


class SimControl(Message):
    """``sim/control`` query: act on the simulated robot (simulator only); answered with `SimState`.

    ``action`` says what to do; each action reads only the fields named with it:

    * ``read``: nothing, just answer the state.
    * ``set_battery``: ``volts`` (open-circuit voltage of the pack).
    * ``press_button``: ``button`` held for ``seconds``, then released.
    * ``hold_button`` / ``release_button``: ``button`` down until released.
    * ``set_dip``: ``dip`` 0..15 (PenguinPi).
    * ``stall``: ``wheel`` blocked (``on``) or free again.
    * ``inject_noise``: icoBoard: flip a bit in each of the next ``count`` frames;
      PenguinPi: flip a bit in each byte with ``probability`` (0 = off). In ``direction``.
    * ``drop_bytes``: lose the next ``count`` bytes on the serial line in ``direction`` (PenguinPi).
    * ``set_gpio``: drive ``line`` (22 button, 10 board request, 11 acknowledge) to ``level``.
    * ``force_descriptor``: an icoBoard v2 START reply says ``sensors``/``actuators``
      instead of the truth (-1 = the truth again).
    * ``delay_replies``: the board's next ``count`` replies leave ``seconds`` late (and what
      follows them waits behind them, as on a real line).
    * ``mark``: start a new window for ``peak_duty`` (its value now is the duty applied now).
    * ``place``: put the robot at ``x``, ``y`` (m), ``theta`` (rad), wheels at rest. Only the
      truth jumps: the encoders do not, so odometry carries on from where it was (docs/sim.md).
    * ``reset``: the world as it started: the robot at the origin at rest, the pack full, no
      wheel stalled (the encoders and odometry carry on, as with ``place``).
    * ``pause`` / ``resume``: freeze the world (the robot stays where it is, its encoders do not
      count) and let it go again; the board keeps running, so a stop still reaches it.
    """

    action: Literal["read", "set_battery", "press_button", "hold_button", "release_button",
                    "set_dip", "stall", "inject_noise", "drop_bytes", "set_gpio",
                    "force_descriptor", "delay_replies", "mark",
                    "place", "reset", "pause", "resume"] = "read"
    volts: float = 0.0
    """V."""
    button: int = 10
    """10 = the SDN shutdown button (GPIO22); 0..3 = the PenguinPi HAT's S1..S4."""
    seconds: float = 0.1
    """How long ``press_button`` holds the button, or how late ``delay_replies`` sends, s."""
    dip: int = 0
    wheel: Literal["left", "right"] = "left"
    on: bool = True
    count: int = 1
    probability: float = 0.0
    direction: Literal["rx", "tx"] = "rx"
    """"rx": host to board (requests), "tx": board to host (replies)."""
    line: int = 22
    level: int = 0
    sensors: int = -1
    actuators: int = -1
    x: float = 0.0
    """``place``: m, world frame."""
    y: float = 0.0
    """``place``: m, world frame."""
    theta: float = 0.0
    """``place``: rad, counter-clockwise from +x."""


class SimState(Message):
    """Answer to ``sim/control``: the simulated robot's true state after the action."""

    stamp: int
    sim_time: float
    """Simulated time since the simulator started, s."""
    seed: int
    """The world's random seed (rerun with it to repeat a run)."""
    board: str
    """"penguinpi", "icoboard-v1" or "icoboard-v2"."""
    x: float
    y: float
    theta: float
    duty_left: float
    """PWM duty applied to the left motor, fraction in [-1, 1]."""
    duty_right: float
    speed_left: float
    """True left rim speed, m/s."""
    speed_right: float
    battery_voltage: float
    """V, under the present load."""
    battery_current: float
    """A."""
    last_frame: bytes = b""
    """The last frame the board received, as it arrived."""
    bad_frames: int = 0
    """Frames the board rejected (bad length, CRC or opcode) since start."""
    watchdog_trips: int = 0
    """icoBoard v2: times the board watchdog stopped the wheels."""
    gpio_button: int = 1
    """GPIO22 level (0 = shutdown button pressed)."""
    gpio_request: int = 1
    """GPIO10 level (0 = the board asks the Pi to shut down)."""
    gpio_ack: int = 0
    """GPIO11 level (1 = the Pi's shutdown daemon is alive)."""
    peak_duty: float = 0.0
    """Largest PWM duty (either wheel, fraction in [0, 1]) applied since the last ``mark``."""
    ticks_left: int = 0
    """True encoder position of the left wheel, counts (unbounded; what the board counts)."""
    ticks_right: int = 0
    integrator_left: int = 0
    """PenguinPi: the firmware PI controller's integral term (its ``sum``) for the left motor
    (0 on the icoBoard, whose controller runs in hwbridge)."""
    integrator_right: int = 0
    zero_duty_since: float = -1.0
    """Simulated time since which both wheels' duty has been 0, s (-1 while a wheel is driven)."""
    counts_changed: float = 0.0
    """Simulated time of the last change of either true encoder count, s (the wheels have been
    still since)."""
    leds: int = 0
    """The board's LEDs lit now, bit n-1 = LED n (PenguinPi: 1 red, 2..4 yellow); 0 on the icoBoard."""
    collided: bool = False
    """True while the robot pushes against an obstacle of the world."""
    collisions: int = 0
    """Times the robot has run into an obstacle since the simulator started."""
    paused: bool = False
    """The world is frozen (``pause``): the robot does not move until ``resume``."""


class OledFrame(Message):
    """``oled/frame``: the picture on the little screen."""

    width: int
    height: int
    pixels: bytes
    """1 bit per pixel, row-major, most significant bit first; width * height / 8 bytes."""


# --------------------------------------------------------------------------- the lap judge (out)


class JudgeEvent(Message):
    """One thing the lap judge saw (services/judge, docs/judge.md): a lap's start or end, a penalty
    (``tyre_off``, ``bogged``, ``ran_stop``) or a stop at a stop sign that counted (``stopped``)."""

    stamp: int
    """When it happened, ns since the epoch (the simulator's truth's clock; a line crossing's time
    is interpolated between two truth samples)."""
    kind: Literal["lap_start", "lap_end", "tyre_off", "bogged", "ran_stop", "stopped"]
    lap: int = 0
    """The lap it counts in (1 = the first; 0 = before the first lap started: no penalty)."""
    penalty: float = 0.0
    """Seconds it adds to the lap's score (0 for lap_start, lap_end, stopped, and before a lap)."""
    x: float = 0.0
    """Where the robot's centre was, world frame, m."""
    y: float = 0.0
    """m."""
    text: str = ""
    """What happened, in words ("left tyre off the road")."""


class JudgeState(Message):
    """``judge/state``: the lap in progress, a few times a second (``judge.rate_hz``)."""

    stamp: int
    """The newest truth sample's time, ns since the epoch."""
    track: str
    """The track's name."""
    lap: int
    """The lap in progress (1 = the first); 0 before the robot first crossed the start line."""
    lap_time: float
    """Time since the lap started, s (0 before the first lap)."""
    penalties: float
    """Penalty seconds of this lap so far."""
    tyre_off: int = 0
    """Tyres that left the road in this lap (+1 s each)."""
    bogged: int = 0
    """Times the whole robot left the road in this lap (+5 s each)."""
    ran_stop: int = 0
    """Stop signs passed without a stop in this lap (+10 s each)."""
    laps: int = 0
    """Laps finished so far."""
    best_score: float = 0.0
    """Best score of a finished lap, s (0 = none finished)."""
    events: list[JudgeEvent] = []
    """The latest events (up to 10), oldest first."""


class JudgeLap(Message):
    """``judge/lap``: one lap's result, once at its end (and the results file's lines)."""

    stamp: int
    """When the lap ended (crossed the start/finish line), ns since the epoch."""
    track: str
    lap: int
    """1 = the first lap."""
    time: float
    """Delivery time: from crossing the start line to crossing it again, s."""
    penalties: float
    """Sum of the penalties, s."""
    reward: float
    """The no-penalty reward, s (5 when the lap had no penalty, else 0)."""
    score: float
    """time + penalties - reward, s (the workshop's score: lower is better)."""
    tyre_off: int = 0
    bogged: int = 0
    ran_stop: int = 0
    finished: bool = True
    """False for a lap cut short by the judge's end (written to the results file only)."""
    events: list[JudgeEvent] = []
    """The lap's events in order (up to 200)."""


# --------------------------------------------------------------------------- housekeeping


class Log(Message):
    """``log``: a log line from a service."""

    stamp: int
    level: Literal["debug", "info", "warning", "error", "critical"]
    service: str
    text: str


class Clock(Message):
    """``clock``: the time of a recording being replayed (``icefloe replay --clock``).

    A service that needs "now" in robot time (rather than the stamps of what it receives) can
    follow this while a recording is replayed, as ROS nodes follow ``/clock``.
    """

    stamp: int
    """The recording's time at the play head, ns since the epoch (the receive times in the file)."""
    rate: float = 1.0
    """Recorded seconds per wall-clock second."""


class RobotInfo(Message):
    """``info`` query answer: what this robot is."""

    name: str
    board: str
    """"penguinpi" or "icoboard"."""
    backend: str
    """"hardware" or "sim"."""
    wheel_diameter: float
    """m."""
    track: float
    """Distance between the wheel contact points, m."""
    ticks_per_rev: int
    max_wheel_speed: float
    """m/s."""
    wheelbase: float = 0.0
    """The virtual car's (``cmd/car``): from its rear axle to its front axle, m (0 = not said)."""
    max_steer: float = 0.0
    """The virtual car's largest steering angle either way, rad (0 = not said)."""
