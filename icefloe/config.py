"""Robot configuration: one TOML file per robot, named like the robot (``deploy/robots/sim.toml``).

`load` takes a robot name (looked up in your own folder, the machine's, then the shipped
configs: see `icefloe.paths`) or a path. A file may start with ``extends = "other.toml"``
(relative to its own folder, or a robot name such as ``"sim"``): its tables are merged over
the other file's, so a lab keeps one base file and twenty short robot files. A bad file raises
`ConfigError` naming the file and the key, and nothing starts.

Strings may contain ``{run_dir}`` (the robot's runtime folder, for sockets and
pseudo-terminals), ``{name}`` (the robot's name) and ``{python}`` (the Python icefloe runs
on, for your own Python programs).

The runtime folder is private to the user the services run as (`private_dir`): by default
``$XDG_RUNTIME_DIR/icefloe/<name>`` (the user's own runtime folder, made by the login
manager), or ``<tmp>/icefloe-<uid>/<name>`` where there is none. Nothing in it is shared
with other users of the machine: the simulator's sockets, the router's password file.

Your own services are ``[programs.<name>]`` tables (`Program`): any program, in any
language, that `icefloe up` runs beside its own services (docs/own-services.md). A program's
folder (``cwd``) defaults to the folder of the file that defines it, so a config and its
programs travel together, also through ``extends``.
"""

from __future__ import annotations

import math
import os
import stat
import sys
import tempfile
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta

from . import paths
from .errors import ConfigError
from .schemas import messages as m

DEFAULT_ROBOT = "sim"
"""The robot a command means when none is named: the simulated one."""
ALL_SERVICES = ("info", "sim", "hwbridge", "odometry", "localizer", "camera", "power", "oled", "webapi")

OPTIONAL_SERVICES = ("grid", "planner", "follower", "mapper", "slam", "ros2", "judge")
"""icefloe's services `icefloe up` starts only when ``services`` names them (docs/planning.md,
docs/slam.md, docs/judge.md): a course turns them on; a robot that does not use them pays nothing for them."""

# Value ranges, checked when a file is read: a bad value is a ConfigError naming its key
# ("robot.toml: hwbridge.deadman_s: Expected `float` > 0.0") and nothing starts.
Positive = Annotated[float, Meta(gt=0)]
NonNegative = Annotated[float, Meta(ge=0)]
Hz = Annotated[float, Meta(gt=0, le=10_000)]
Seconds = Annotated[float, Meta(gt=0, le=86_400)]
Count = Annotated[int, Meta(ge=1)]
Line = Annotated[int, Meta(ge=0, le=1023)]
"""A GPIO line number."""
Port = Annotated[int, Meta(ge=1, le=65_535)]


class Section(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Base of every config table: unknown keys are errors (a typo must not pass silently), and so
    are infinite numbers (TOML has ``inf`` and ``nan``)."""

    def __post_init__(self) -> None:
        for name in self.__struct_fields__:
            value = getattr(self, name)
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"`{name}` must be a finite number, got {value}")


class Board(Section):
    """The I/O board and how to reach it."""

    kind: Literal["penguinpi", "icoboard"] = "penguinpi"
    backend: Literal["hardware", "sim"] = "sim"
    """"hardware": the real board; "sim": the simulator's model of it (same wire protocol)."""
    serial_port: str = "/dev/serial0"
    """PenguinPi: the serial device (the simulator's pseudo-terminal in sim)."""
    baud: Count = 115200
    spi_device: str = "/dev/spidev0.0"
    """icoBoard: the SPI device on the Pi."""
    spi_speed_hz: Count = 1_000_000
    """icoBoard: SPI clock, Hz (icefloe's gateware takes 100 kHz .. 16.7 MHz, docs/gateware.md)."""
    sim_socket: str = "{run_dir}/icoboard.sock"
    """icoBoard in sim: the simulator's datagram socket (one datagram = one SPI exchange)."""
    protocol: Literal[1, 2] = 2
    """icoBoard SPI protocol version."""
    sensors: Annotated[int, Meta(ge=0, le=255)] = 2
    """icoBoard: number of sensors (encoders), M."""
    actuators: Annotated[int, Meta(ge=0, le=255)] = 2
    """icoBoard: number of actuators (PWM), N."""
    pwm_hz: Positive = 20000.0
    """icoBoard: PWM frequency of the motor outputs the gateware makes, Hz (docs/gateware.md)."""


class Geometry(Section):
    wheel_diameter: Positive = 0.065
    """m."""
    track: Positive = 0.156
    """Distance between the wheels' contact points, m."""
    ticks_per_rev: Count = 384
    """Encoder counts per wheel turn."""
    radius: Positive = 0.1
    """Radius of a disc around the robot's centre that holds all of it, m (the simulator's
    collisions with obstacles; the planner keeps its centre this far from them)."""


MIN_REST_RATE_HZ = 25.0
"""The slowest a resting cycle may run, Hz: the icoBoard's watchdog zeroes its duty after 50 ms
without a frame (docs/gateware.md), and a frame every 40 ms keeps it quiet."""


class Hwbridge(Section):
    rate_hz: Hz = 1000.0
    """Real-time cycle rate. The PenguinPi link cannot hold 1 kHz at 115200 baud; see docs."""
    serial_rate_hz: Hz = 200.0
    """PenguinPi: exchange rate on the serial link (MULTI_SET_VEL_GET_ENC)."""
    wheels_rate_hz: Annotated[float, Meta(ge=0, le=10_000)] = 50.0
    """Rate of ``hw/wheels`` on the bus, Hz (0 = every cycle). 50, odometry's own rate: each
    sample carries cumulative counts, so a slower stream loses no motion, and at 100 Hz every
    sample cost hwbridge, the router and odometry again while driving (issue 35, docs/deploy.md)."""
    deadman_s: Seconds = 0.5
    """Wheels stop when no command arrived for this long."""
    max_wheel_speed: Positive = 0.5
    """Commands are clamped to this rim speed, m/s."""
    max_accel: Positive = 2.0
    """Commanded rim speed changes at most this fast, m/s^2."""
    priority: Annotated[int, Meta(ge=1, le=99)] = 80
    """SCHED_FIFO priority of the cycle (if the OS allows it)."""
    cpu: Annotated[int, Meta(ge=-1)] = -1
    """CPU to pin the cycle to (-1 = the last CPU)."""
    kp: NonNegative = 20000.0
    """icoBoard wheel PI controller: duty counts (32767 = 100 %) per (m/s) of speed error.
    The motors need ~48000 counts per m/s at steady state (docs/hwbridge.md)."""
    ki: NonNegative = 200000.0
    """Duty counts per (m/s * s) of integrated error (integral time kp/ki = 0.1 s)."""
    speed_window_s: Seconds = 0.05
    """Measured wheel speed = encoder counts over this window, s (one count is ~0.5 mm)."""
    rest_rate_hz: Annotated[float, Meta(ge=0, le=10_000)] = 50.0
    """Cycle rate while the robot rests, Hz: no motion command, the stop confirmed by the board,
    the encoders still for ``rest_after_s`` (0, or ``rate_hz`` or more: the cycle never rests).
    A motion command wakes the cycle at once (SIGUSR1), so resting costs a command no latency;
    what the rate sets is how often a still robot is watched. 50 Hz: the icoBoard's watchdog wants
    a frame every 50 ms (hence at least 25 Hz); the PenguinPi alternates its encoders and its polls
    (battery, button presses, which the board counts, DIP), each 25 times a second; a wheel pushed
    by hand wakes the cycle within 40 ms; and it is a fifth of the 1 kHz cycle's CPU."""
    rest_after_s: Annotated[float, Meta(ge=0.1, le=60)] = 1.0
    """How long the robot must stand (the stop confirmed, the encoders unchanged) before the cycle
    rests, s: a robot between two commands of a script does not rest and wake each time. At least
    0.1 s: the bus side wakes a rest once, so a flood of commands costs at most one SIGUSR1 per
    this long."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if 0 < self.rest_rate_hz < min(MIN_REST_RATE_HZ, self.rate_hz):
            raise ValueError(f"`rest_rate_hz` must be 0 (never rest) or at least {MIN_REST_RATE_HZ:g} Hz, "
                             f"got {self.rest_rate_hz:g}: the icoBoard's watchdog stops the wheels after 50 ms "
                             "without a frame")

    @property
    def rests(self) -> bool:
        """Whether the cycle slows down to ``rest_rate_hz`` at rest."""
        return 0 < self.rest_rate_hz < self.rate_hz


class Car(Section):
    """The virtual car hwbridge drives on ``cmd/car`` (``[car]``, docs/motion-models.md): a
    bicycle-model car whose rear axle is the drive wheels' axle.

    There is no other place for it: a differential base turns about a point on its wheels' axle,
    as a car turns about a point on its rear axle's line, and a rear axle anywhere else would have
    to slide sideways in every turn. What the config chooses is which end of the robot is the
    car's front (``facing``)."""

    wheelbase: Annotated[float, Meta(ge=0.02, le=5.0)] = 0.15
    """From the rear axle (the drive wheels) to the front axle, m."""
    max_steer: Annotated[float, Meta(gt=0, le=1.3)] = 0.6
    """Largest steering angle either way, rad (a larger ``cmd/car`` is clipped, with a log line)."""
    steer_rate: Annotated[float, Meta(gt=0, le=50)] = 1.5
    """How fast the steering turns, rad/s (a car cannot jump from full left to full right)."""
    facing: Literal["forward", "backward"] = "forward"
    """Where the car's front is: "forward", the robot's front (the front axle ``wheelbase`` ahead of
    the drive wheels); "backward", the robot's back (the car drives castor first)."""
    state_rate_hz: Annotated[float, Meta(gt=0, le=200)] = 50.0
    """Rate of ``car/state`` while the car moves or steers, and of the steering's steps, Hz."""


class Camera(Section):
    """The robot's camera and what it costs (docs/camera.md, "What the camera costs"): detection's
    CPU is about proportional to ``width`` x ``height`` x ``detection_rate_hz``."""

    source: str = "sim"
    """"sim", "picamera2", "v4l2:<index or path>", or a folder/video file to replay."""
    width: Annotated[int, Meta(ge=64, le=4096)] = 640
    """Frame width, pixels: what is captured and searched for markers (the simulator renders it)."""
    height: Annotated[int, Meta(ge=48, le=4096)] = 480
    """Frame height, pixels."""
    fps: Annotated[float, Meta(gt=0, le=120)] = 15.0
    """Frames captured a second (what ``camera/frames`` streams to a watcher)."""
    detection_rate_hz: Annotated[float, Meta(ge=0, le=120)] = 0.0
    """Frames searched for markers a second, the camera's main cost (0 = every captured frame;
    at most ``fps``). The PenguinPi's Raspberry Pi 3B: deploy/robots/penguin1.toml."""
    rest_detection_rate_hz: Annotated[float, Meta(gt=0, le=120)] = 1.0
    """Frames searched for markers a second while the camera rests, Hz: its picture has not changed
    (``still_threshold``) for ``rest_after_s``. A still robot sees the same markers in every frame;
    1 Hz keeps the localizer, SLAM and the map maker seeing them (and a client's 5 s wait for
    ``camera/landmarks`` met) at a fifteenth of the cost. At least ``detection_rate_hz`` (or ``fps``)
    means the camera never rests. docs/camera.md, "The camera at rest"."""
    rest_after_s: Annotated[float, Meta(ge=0, le=3600)] = 1.0
    """The picture must stay still this long before the camera rests, s: a robot pausing between two
    moves keeps its full detection rate, and the localizer gets a second of sightings of a new view."""
    still_threshold: Annotated[float, Meta(gt=0, le=10)] = 0.25
    """The largest change of one cell of the picture's 32 x 24 thumbnail, in the picture's mean
    brightness, that still counts as the same picture (services/camera/rest.py). Measured by
    bench/camera_rest.py: a standing robot's frames differ by up to 0.15 (sensor noise, flicker,
    JPEG), a robot turning at 0.5 rad/s crosses 0.25 within two frames, a marker 24 to 40 px wide put
    into a still picture changed it by 0.7 to 0.9."""
    image_rate_hz: Annotated[float, Meta(ge=0, le=10_000)] = 2.0
    """Rate of ``camera/image`` on the bus (Wi-Fi is shared by a class)."""
    image_width: Count = 320
    image_height: Count = 240
    jpeg_quality: Annotated[int, Meta(ge=0, le=100)] = 70
    dictionary: str = "DICT_4X4_50"
    marker_size: Positive = 0.12
    """Printed side of a marker's black square, m, for ids the world map does not list."""
    calibration: str = ""
    """Calibration file (OpenCV YAML/JSON with camera_matrix, dist_coeffs, and what `icefloe calibrate`
    measured of the marker detector and the capture latency); "" = nominal. A relative path is relative
    to the config file that sets it."""
    focal_px: Positive = 500.0
    """Nominal focal length in pixels when there is no calibration file."""
    mount_x: float = 0.05
    """Camera position ahead of the robot's centre, m."""
    mount_y: float = 0.0
    mount_z: float = 0.10
    """Camera height above the floor, m."""
    mount_yaw: float = 0.0
    """Camera heading relative to the robot's, rad."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.detection_rate_hz > self.fps:
            raise ValueError(f"detection_rate_hz ({self.detection_rate_hz:g}) must be at most fps ({self.fps:g}): "
                             "detection cannot search frames that were never captured")
        if self.rest_detection_rate_hz > self.fps:
            raise ValueError(f"rest_detection_rate_hz ({self.rest_detection_rate_hz:g}) must be at most fps "
                             f"({self.fps:g}): detection cannot search frames that were never captured")
        if self.image_width > self.width or self.image_height > self.height:
            raise ValueError(f"image_width x image_height ({self.image_width}x{self.image_height}) must fit in "
                             f"width x height ({self.width}x{self.height}): the images are the frames made smaller")

    @property
    def detection_hz(self) -> float:
        """Frames searched for markers a second: ``detection_rate_hz``, or ``fps`` when that is 0."""
        return self.detection_rate_hz or self.fps


class Extloc(Section):
    """The robot's top marker, for the lab's overhead camera (``[extloc]``, docs/extloc.md).

    An ArUco marker of the overhead camera's dictionary (``overhead.dictionary``), printed
    with a white border of one cell, lying flat on top of the robot, centred over its centre,
    its top edge towards the robot's front. The lab's localizer reads it from here."""

    marker_id: Annotated[int, Meta(ge=-1, le=999)] = -1
    """Its ArUco id (-1 = the robot has no top marker)."""
    marker_size: Annotated[float, Meta(gt=0, le=1)] = 0.16
    """Side of its black square, m."""
    marker_height: Annotated[float, Meta(ge=0, le=2)] = 0.12
    """Height of the marker above the floor, m."""
    group: Annotated[int, Meta(ge=0, le=9999)] = 0
    """The old localiser's group number (``GET /pose/get?group=N``) that means this robot (0 = none)."""


class Overhead(Section):
    """The lab's overhead camera and its localizer (``services/extloc``, in the lab's config;
    docs/extloc.md)."""

    robots: list[str] = []
    """The robots it looks for: robot names or config paths (each config's ``[extloc]``)."""
    source: str = "sim"
    """"sim" (a rendered top-down view of the robots' ``sim/truth``), "picamera2",
    "v4l2:<index or path>", or an image folder / video file to replay."""
    width: Count = 1280
    height: Count = 720
    fps: Hz = 30.0
    dictionary: str = "DICT_4X4_100"
    """ArUco dictionary of the robots' top markers and the floor markers."""
    calibration: str = ""
    """The camera's intrinsics (``icefloe calibrate``'s file); "" = nominal from ``focal_px``. A relative
    path is relative to the config file that sets it."""
    focal_px: Positive = 410.0
    """Nominal focal length without a calibration file, pixels."""
    pose: str = ""
    """The camera's pose on the floor (``icefloe extloc calibrate``'s file); "" = found from the
    floor markers at start."""
    world: str = "lab"
    """The world file with the floor markers (``[[floor_marker]]``)."""
    http_port: Annotated[int, Meta(ge=0, le=65_535)] = 8081
    """The old localiser's HTTP API (``/pose/get``, ``/camera/get``); 0 = none."""
    http_host: str = "0.0.0.0"
    image_rate_hz: Annotated[float, Meta(ge=0, le=100)] = 2.0
    """How often the pictures of ``/camera/get`` and ``/camera/frame`` are encoded, Hz."""
    old_square_x: Annotated[float, Meta(ge=-1000, le=1000)] = -0.5
    """Where the old localiser's 2 m square lies in the world: its corner (the old API's x, y = 0, 0),
    world frame, m. The default puts it on the lab world's clear 2 m square, x and y in [-0.5, 1.5] m
    (docs/extloc.md)."""
    old_square_y: Annotated[float, Meta(ge=-1000, le=1000)] = -0.5
    old_square_yaw: Annotated[float, Meta(ge=-math.tau, le=math.tau)] = 0.0
    """Direction of the old square's +x axis in the world, rad CCW from the world's +x (its +y is
    90 degrees CCW from that: the old frame is right-handed, as seen from above)."""
    sim_x: float = 0.0
    """The simulated camera's lens, world frame, m."""
    sim_y: float = 0.0
    sim_z: Annotated[float, Meta(gt=0.3, le=20)] = 2.5
    sim_yaw: float = 0.0
    """Where the top of the simulated picture points on the floor, rad CCW from +x."""
    sim_tilt: Annotated[float, Meta(ge=-0.5, le=0.5)] = 0.0
    """The simulated camera's tilt from straight down, rad (about the picture's horizontal axis)."""
    sim_noise: NonNegative = 2.0
    """Pixel noise of the simulated picture, grey levels (standard deviation)."""
    sim_seed: Annotated[int, Meta(ge=1)] = 1


class Power(Section):
    source: Literal["board", "sim", "i2c"] = "board"
    low_v: Positive = 7.0
    critical_v: Positive = 6.5
    critical_readings: Count = 5
    """Consecutive critical readings before shutting down."""
    pole: Annotated[float, Meta(ge=0, lt=1)] = 0.9
    """First-order filter pole (0 = no filtering)."""
    poweroff_command: Annotated[list[str], Meta(min_length=1)] = msgspec.field(default_factory=lambda: ["true"])
    """What powers the machine off, e.g. ["sudo", "systemctl", "poweroff"]."""
    gpio_chip: str = "/dev/gpiochip0"
    button_line: Line = 22
    request_line: Line = 10
    ack_line: Line = 11
    gpio: Literal["gpiod", "sim", "none"] = "sim"
    """GPIO backend: "gpiod" (the Pi's lines), "sim" (the simulator's lines on `sim/gpio`), "none"."""
    debounce_s: Seconds = 0.02
    """Edges closer together than this are one bounce burst, s."""
    button_hold_s: Seconds = 0.5
    """The shutdown button must be held this long, s (like the old GPIOSoftShutdown daemon)."""
    request_hold_s: Seconds = 15.0
    """The board's request line must stay low this long, s (reflashing over SPI toggles it)."""
    halt_timeout_s: Seconds = 5.0
    """How long to wait for hwbridge to confirm the wheels stopped (`cmd/halt`), s
    (longer than hwbridge's own 3 s, so we hear its answer)."""
    silent_s: Seconds = 5.0
    """Battery readings that stop this long while the state is low start a shutdown, s
    (the PenguinPi firmware halts itself, and its readings, at 6.5 V)."""
    ack_delay_s: NonNegative = 0.5
    """Pause after dropping the acknowledge line, before powering off, s (the board shows its message)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.critical_v >= self.low_v:
            raise ValueError(f"critical_v ({self.critical_v} V) must be below low_v ({self.low_v} V)")


class Display(Section):
    kind: Literal["penguinpi", "ssd1306", "none"] = "penguinpi"
    i2c_port: Annotated[int, Meta(ge=0)] = 1
    i2c_address: Annotated[int, Meta(ge=0, le=0x7F)] = 0x3C
    rate_hz: Annotated[float, Meta(gt=0, le=100)] = 5.0


class Odometry(Section):
    """Dead reckoning from the wheel encoders (services/odometry, docs/odometry.md)."""

    rate_hz: Hz = 50.0
    """Rate of ``odom/pose`` on the bus while the pose changes, Hz."""
    rest_rate_hz: Hz = 4.0
    """Rate of ``odom/pose`` while the pose does not change (the robot stands), Hz: a heartbeat
    (`icefloe.heartbeat`). 4 Hz is a pose every 0.25 s, twice within the follower's
    ``pose_timeout_s`` (0.5 s) and four times within the web API's bus timeout (1 s); a change is
    published at once. At least ``rate_hz`` means a pose every period, as before."""
    max_wheel_speed: Positive = 1.0
    """Plausibility limit, m/s: a count step faster than this (plus `jump_margin`) is a glitch, not motion."""
    jump_margin: NonNegative = 0.005
    """Allowance per sample on top of ``max_wheel_speed * dt``, m (timestamp jitter, one count)."""
    gap_s: Seconds = 0.25
    """A silence on ``hw/wheels`` longer than this is logged (the motion across it is still integrated), s."""
    speed_window_s: Seconds = 0.1
    """v and w are averaged over this much recent motion, s."""


class Localizer(Section):
    world: str = "lab"
    """Landmark map: a world name (``lab``: ``deploy/worlds/lab.toml`` or your own, see `icefloe.paths`) or a path."""
    rate_hz: Hz = 20.0
    """Steady rate of ``loc/pose`` while the estimate changes (odometry moved), Hz: it is published
    after every landmark frame, and at each tick of this rate that no frame's pose went out
    before (so while the camera finds markers at 15 Hz, about 20 poses a second, not 15 + 20).
    The newest ``odom/pose`` is read at these times, not followed at its own rate."""
    rest_rate_hz: Hz = 4.0
    """Rate of ``loc/pose`` while neither odometry nor the landmarks changed the estimate, Hz: a
    heartbeat (`icefloe.heartbeat`). 4 Hz is a pose every 0.25 s, twice within the follower's
    ``pose_timeout_s`` (0.5 s); a change is published at once. At least ``rate_hz`` means a pose
    every period, as before."""
    init: Literal["config", "landmarks"] = "config"
    """Initial pose: "config" = initial_* below; "landmarks" = solved from the first frame with >= 2 known markers."""
    initial_x: float = 0.0
    """m."""
    initial_y: float = 0.0
    """m."""
    initial_theta: float = 0.0
    """rad."""
    initial_sigma_xy: Positive = 0.1
    """Standard deviation of the initial position, m."""
    initial_sigma_theta: Positive = 0.1
    """Standard deviation of the initial heading, rad."""
    sigma_range: Positive = 0.03
    """Landmark range noise, m (standard deviation, at any range)."""
    sigma_range_rel: NonNegative = 0.02
    """Landmark range noise that grows with range, fraction of the range."""
    sigma_bearing: Positive = 0.02
    """Landmark bearing noise, rad."""
    odom_sigma_d: NonNegative = 0.02
    """Odometry distance noise, m per sqrt(m) travelled (random walk)."""
    odom_sigma_theta: NonNegative = 0.03
    """Odometry heading noise from turning, rad per sqrt(rad) turned."""
    odom_sigma_theta_d: NonNegative = 0.03
    """Odometry heading noise from driving, rad per sqrt(m) travelled (slip, wheel radius errors)."""
    gate_chi2: Positive = 11.83
    """Mahalanobis gate on (range, bearing): chi-square, 2 degrees of freedom (11.83 = 99.73 %, "3 sigma")."""
    relocalize_after: Annotated[int, Meta(ge=0)] = 30
    """Lost: after this many sightings in a row fail the gate, restart from the next frame
    showing >= 2 known markers (0 = never)."""


class Mapper(Section):
    """The reference map maker: landmark map from a known pose (services/mapper, docs/slam.md).
    Its sighting noise is the localizer's (``[localizer]`` sigma_range, sigma_range_rel, sigma_bearing)."""

    pose: Literal["extloc/pose", "sim/truth"] = "sim/truth"
    """Where the known pose comes from: an external localizer (motion capture, an overhead
    camera) on ``extloc/pose``, or the simulator's truth."""
    pose_sigma_xy: NonNegative = 0.005
    """How far off that pose may be, m (standard deviation)."""
    pose_sigma_theta: NonNegative = 0.005
    """rad (standard deviation)."""
    rate_hz: Annotated[float, Meta(gt=0, le=50)] = 2.0
    """``map/landmarks`` per second (once there is a landmark)."""
    gate_chi2: Positive = 11.83
    """Mahalanobis gate on (range, bearing), chi-square 2 degrees of freedom."""
    max_landmarks: Annotated[int, Meta(ge=1, le=1000)] = 100
    """Landmarks kept at most; sightings of more are ignored (and logged)."""


class Slam(Section):
    """The reference EKF-SLAM (services/slam, docs/slam.md). Its odometry and sighting noise are
    the localizer's (``[localizer]``)."""

    rate_hz: Annotated[float, Meta(gt=0, le=100)] = 20.0
    """``slam/pose`` per second (it is also published after every landmark frame)."""
    map_rate_hz: Annotated[float, Meta(gt=0, le=50)] = 2.0
    """``slam/map`` per second."""
    gate_chi2: Positive = 11.83
    """Mahalanobis gate on (range, bearing), chi-square 2 degrees of freedom."""
    max_landmarks: Annotated[int, Meta(ge=1, le=1000)] = 100
    """Landmarks kept at most (the state grows by 2 numbers each, the update as its square)."""


class Planner(Section):
    """The occupancy grid and the reference planner (services/grid, services/planner; docs/planning.md)."""

    world: str = ""
    """The world whose obstacles make the grid: a world name or a path ("" = ``localizer.world``)."""
    resolution: Annotated[float, Meta(ge=0.005, le=1.0)] = 0.02
    """Side of a grid cell, m."""
    clearance: Annotated[float, Meta(ge=0, le=1.0)] = 0.05
    """Room kept between the robot and an obstacle, beyond ``geometry.radius``, m: the planner
    plans for a point on the grid inflated by radius + clearance."""
    max_waiting: Annotated[int, Meta(ge=0, le=32)] = 4
    """Plan queries that may wait while one is being planned; more are answered "busy" at once."""


class Follower(Section):
    """The reference path follower: pure pursuit (services/follower; docs/planning.md)."""

    pose: Literal["loc/pose", "odom/pose", "sim/truth"] = "loc/pose"
    """Where the robot is: the localizer (the world frame the planner plans in), odometry, or
    the simulator's truth (tests and benchmarks only)."""
    rate_hz: Annotated[float, Meta(gt=0, le=100)] = 20.0
    """Commands on ``cmd/twist`` per second while following."""
    speed: Annotated[float, Meta(gt=0, le=1.0)] = 0.15
    """Forward speed, m/s (a path's own ``speed`` replaces it, up to ``max_speed``)."""
    max_speed: Annotated[float, Meta(gt=0, le=1.0)] = 0.3
    """Fastest forward speed a path may ask for, m/s."""
    lookahead: Annotated[float, Meta(gt=0, le=2.0)] = 0.15
    """Distance ahead along the path of the point steered at, m."""
    max_turn_rate: Annotated[float, Meta(gt=0, le=10.0)] = 1.5
    """Fastest turn, rad/s."""
    turn_in_place: Annotated[float, Meta(gt=0, le=3.2)] = 0.5
    """Turn on the spot first when the point steered at is more than this off the heading, rad."""
    goal_tolerance: Annotated[float, Meta(gt=0, le=1.0)] = 0.03
    """Arrived when the robot's centre is this close to the path's last point, m."""
    pose_timeout_s: Seconds = 0.5
    """Stop when no pose came for this long while following, s."""


class Judge(Section):
    """The lap judge of a track world: RVSS "Need 4 Speed"'s lap time, penalties and reward from the
    simulator's truth (services/judge, docs/judge.md)."""

    world: str = ""
    """The world whose track is judged: a world name or a path ("" = ``sim.world``)."""
    rate_hz: Annotated[float, Meta(gt=0, le=50)] = 5.0
    """``judge/state`` per second."""
    results: str = "{run_dir}/judge.jsonl"
    """The results file: one JSON line per lap (`JudgeLap`), appended as each lap ends, and the lap
    in progress when the judge stops ("" = none)."""
    stop_zone: Annotated[float, Meta(gt=0, le=1.0)] = 0.10
    """How far before a stop sign's line the robot's front may stop, m (the workshop's 10 cm)."""
    stop_dwell_s: Annotated[float, Meta(gt=0, le=10.0)] = 0.5
    """Stopped = stood still this long, s (docs/judge.md says why)."""
    stop_tolerance: Annotated[float, Meta(gt=0, le=0.05)] = 0.005
    """Standing still = the centre moved at most this far, m."""


class Ros2(Section):
    """ROS 2 topics in rmw_zenoh's form on the robot's own router (services/ros2; docs/ros2.md)."""

    distro: Literal["humble", "jazzy", "kilted", "rolling"] = "jazzy"
    """The ROS 2 distribution whose type hashes the keys carry (Humble's rmw_zenoh writes none)."""
    domain_id: Annotated[int, Meta(ge=0, le=232)] = 0
    """``ROS_DOMAIN_ID`` of the ROS 2 users (0-232, as ROS 2 allows)."""
    namespace: Annotated[str, Meta(pattern=r"^(/[A-Za-z][A-Za-z0-9_]*)*$")] = ""
    """The topics' namespace, ``/penguin1`` ("" = ``/<robot name>``)."""
    odom_frame: Annotated[str, Meta(pattern=r"^[A-Za-z_][A-Za-z0-9_/]*$")] = "odom"
    """``header.frame_id`` of ``odom``."""
    base_frame: Annotated[str, Meta(pattern=r"^[A-Za-z_][A-Za-z0-9_/]*$")] = "base_link"
    """``child_frame_id`` of ``odom`` and ``tf``."""
    map_frame: Annotated[str, Meta(pattern=r"^[A-Za-z_][A-Za-z0-9_/]*$")] = "map"
    """``header.frame_id`` of ``map``, ``pose`` and ``external_pose``: the world frame (the world map's)."""
    camera_frame: Annotated[str, Meta(pattern=r"^[A-Za-z_][A-Za-z0-9_/]*$")] = "camera_optical_frame"
    """``header.frame_id`` of the camera's topics: OpenCV's axes (x right, y down, z forward), which
    are ROS's optical frame (REP 103)."""
    images: Literal["off", "image", "frames"] = "image"
    """``camera/image_raw/compressed``: "image" = the JPEGs of ``camera/image`` (``camera.image_rate_hz``,
    2 a second, made anyway); "frames" = every captured frame (``camera/frames``: the camera then
    encodes each one, all the time); "off" = none (``camera/camera_info`` still follows ``camera/image``)."""
    map_period_s: Seconds = 5.0
    """How often ``map`` is published again, s (volatile QoS: a ROS 2 user who joins later gets the next)."""


Profile = Literal["realistic", "ideal"]
"""How unkind the simulated robot is (``[sim] profile``; docs/sim.md has the table of effects)."""

Fraction = Annotated[float, Meta(ge=0, le=1)]


class Lens(Section):
    """The simulated camera's true lens: what `icefloe calibrate` measures (``[sim.lens]``).

    The camera service does not read it: it believes ``[camera]`` (``focal_px``, or its
    ``calibration`` file), as it would on a real robot. A key left out takes the profile's value
    (`icefloe.sim.realism`): the realistic profile's lens, or in the ideal profile the lens the
    camera service believes. 0 means "as the nominal camera" (``focal_px``, centred, no distortion).
    """

    fx: Annotated[float, msgspec.Meta(ge=0)] | None = None
    """Focal length along x, pixels (0 = ``camera.focal_px``)."""
    fy: Annotated[float, msgspec.Meta(ge=0)] | None = None
    """Focal length along y, pixels (0 = fx)."""
    cx: Annotated[float, msgspec.Meta(ge=0)] | None = None
    """Principal point, pixels from the left edge (0 = the image centre)."""
    cy: Annotated[float, msgspec.Meta(ge=0)] | None = None
    """Principal point, pixels from the top edge (0 = the image centre)."""
    distortion: Annotated[list[Annotated[float, msgspec.Meta(ge=-10, le=10)]], msgspec.Meta(max_length=5)] | None \
        = None
    """OpenCV distortion coefficients k1, k2, p1, p2[, k3] (empty = none)."""


class SimWheels(Section):
    """The simulated robot's true wheels and motors (``[sim.wheels]``): what a wheel calibration
    measures. The robot's software believes ``[geometry]``; the simulator moves the robot with these.
    A key left out takes the profile's value (`icefloe.sim.realism`, docs/sim.md)."""

    diameter_left: Annotated[float, Meta(gt=0, le=1)] | None = None
    """The left wheel's effective rolling diameter, m (ideal: ``geometry.wheel_diameter``)."""
    diameter_right: Annotated[float, Meta(gt=0, le=1)] | None = None
    """The right wheel's, m."""
    track: Annotated[float, Meta(gt=0, le=2)] | None = None
    """The effective distance between the wheels' contact points, m (ideal: ``geometry.track``)."""
    slip_accel: Annotated[float, Meta(ge=0, le=0.5)] | None = None
    """Fraction of a wheel's travel lost to slip per m/s² of its acceleration (starts and stops), s²/m."""
    slip_turn: Annotated[float, Meta(ge=0, le=0.5)] | None = None
    """Fraction of a turn lost to the wheels scrubbing sideways, per rad/s of turn rate, s/rad."""
    dead_band_left: Annotated[float, Meta(ge=0, lt=100)] | None = None
    """The left motor does not move at this PWM duty or less, %."""
    dead_band_right: Annotated[float, Meta(ge=0, lt=100)] | None = None
    """The right motor's dead band, %."""
    battery_sag: bool | None = None
    """The motors' speed follows the battery's voltage (false: always as at 7.4 V)."""


class SimImage(Section):
    """What the simulated camera's sensor and its pipeline do to a frame (``[sim.image]``).
    A key left out takes the profile's value (`icefloe.sim.realism`, docs/sim.md)."""

    exposure_s: Annotated[float, Meta(ge=0, le=0.5)] | None = None
    """The exposure auto exposure needs where the arena's light is average (shutter time x analogue
    gain), s; dimmer light needs more, bought as the Raspberry Pi camera does: a longer shutter (the
    robot's motion smears the frame over it), then more gain (more noise). 0 = no motion blur."""
    light_variation: Annotated[float, Meta(ge=0, lt=1)] | None = None
    """How much less light the darkest part of the arena gets than the brightest (0 = even)."""
    flicker: Annotated[float, Meta(ge=0, le=1)] | None = None
    """Frame-to-frame brightness change, relative (0.15 = up to ±15 %)."""
    noise: Annotated[float, Meta(ge=0, le=100)] | None = None
    """Sensor noise at unit gain, standard deviation in grey levels (it grows with the gain)."""
    blur_px: Annotated[float, Meta(ge=0, le=10)] | None = None
    """The lens's own softness, Gaussian sigma, px."""
    jpeg_quality: Annotated[int, Meta(ge=0, le=100)] | None = None
    """Each frame JPEG-compressed and decoded at this quality (0 = not compressed)."""
    latency_s: Annotated[float, Meta(ge=0, le=2)] | None = None
    """From the exposure to the frame reaching the camera service, on average, s (the frame's stamp
    is when it arrives, as a real camera's source stamps it)."""
    latency_jitter_s: Annotated[float, Meta(ge=0, le=1)] | None = None
    """Standard deviation of that latency, s."""
    drop_rate: Annotated[float, Meta(ge=0, le=1)] | None = None
    """Fraction of frames the pipeline loses."""


class Sim(Section):
    world: str = "lab"
    """The simulated world: a world name or a path, as `Localizer.world`."""
    profile: Profile = "realistic"
    """"realistic": the wheels, the lens and the pictures of a real PenguinPi, each effect a key of
    ``[sim.wheels]``, ``[sim.lens]`` and ``[sim.image]``, so that code tuned in the simulator works on
    the robot; "ideal": the robot is exactly what its config says (``[geometry]``, the camera's own
    calibration), for debugging and for tests about something other than realism (docs/sim.md)."""
    seed: Annotated[int, Meta(ge=0)] = 0
    """Random seed of every effect: slip, noise, light, latency (0 = pick one and print it)."""
    slip: Fraction | None = None
    """Random wheel slip: relative std dev of ground travel vs rim travel per 1 ms step."""
    encoder_noise: NonNegative | None = None
    """Relative std dev of counted vs turned wheel angle per 1 ms step."""
    truth_rate_hz: Hz = 50.0
    start_x: float = 0.0
    """Where the simulated robot stands at start, world frame, m (robots of a simulated lab apart)."""
    start_y: float = 0.0
    start_theta: float = 0.0
    """Its heading at start, rad."""
    camera: bool = True
    icoboard: Literal["python", "gateware"] = "python"
    """The simulated icoBoard: "python" (the protocol model, sim/icoboard.py) or "gateware"
    (the FPGA design itself, compiled, its pins wired to the world; docs/gateware.md)."""
    gateware_clk_hz: Positive = 1e6
    """icoboard = "gateware": the FPGA clock in the simulation, Hz (the board's is 100 MHz;
    scaled down so the simulation keeps real time)."""
    lens: Lens = Lens()
    """The simulated camera's true lens."""
    wheels: SimWheels = SimWheels()
    """The simulated robot's true wheels and motors."""
    image: SimImage = SimImage()
    """The simulated camera's sensor and pipeline."""


class Webapi(Section):
    """The PenguinPi-compatible HTTP API (``services/webapi``, docs/webapi.md)."""

    host: str = "0.0.0.0"
    port: Port = 8080
    """TCP port of the HTTP server (the old PenguinPi server used 8080)."""
    max_demand: Count = 100
    """Largest wheel speed accepted, in PenguinPi firmware demand units (about 5.3 mm/s each)."""
    max_time: Seconds = 30.0
    """Longest timed motion accepted by /robot/set/velocity, s."""
    camera_get: Literal["stream", "frame"] = "stream"
    """What ``/camera/get`` answers: "stream", the old server's endless MJPEG stream; "frame", one
    JPEG per request (for clients written against a course simulator that serves one image)."""
    wheel_signs: tuple[Literal[1, -1], Literal[1, -1]] = (1, 1)
    """How the old API's clients see each wheel, (left, right): -1 turns that wheel round for
    them, as on a robot whose motor and encoder leads of that wheel were swapped. A fleet whose
    clients negate the right wheel's speed for their physical robots (ECE4078 2023's
    ``set_velocity``: "if right wheel spins backwards") sets ``[1, -1]``: their speeds and counts
    of that wheel are negated on the way in and out, and their code drives straight."""


class Lab(Section):
    """The lab's emergency stop, in the lab machine's config (``icefloe lab stop``; the lab's page,
    ``services/labpage``; docs/lab.md)."""

    folder: str = ""
    """The lab's credentials folder (``icefloe router --lab DIR``'s): the robots to stop, and the
    TA's login (its file whose robot is "*"). "" = none: the robots alive on the bus, or ``--robot``."""
    timeout: Annotated[float, Meta(gt=0, le=10)] = 1.0
    """How long each robot has to confirm a stop, s."""
    page_host: str = "0.0.0.0"
    page_port: Port = 8090
    """The lab's page (``services/labpage``): every robot's stop, for the TA's login only."""


class Zenoh(Section):
    listen: list[str] = msgspec.field(default_factory=lambda: ["tcp/0.0.0.0:7447"])
    """Where the robot's router listens; laptops connect here."""
    connect: list[str] = msgspec.field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    """Where the robot's own services connect (its router)."""
    access_control: bool = False
    """Require credentials: anyone may read, only this robot's user may command it (docs/lab.md)."""
    credentials: str = ""
    """File with this robot's user and password (made by `icefloe credentials`; never committed)."""
    user: str = ""
    """Zenoh user (normally read from `credentials`)."""
    password: str = ""
    tls_certificate: str = ""
    """Router: this robot's TLS certificate (PEM), for ``tls/...`` endpoints in ``listen`` (docs/lab.md)."""
    tls_private_key: str = ""
    """Router: the certificate's private key (PEM)."""
    tls_root_ca: str = ""
    """Clients: the lab's CA certificate (PEM), to trust a router on a ``tls/...`` endpoint."""
    lab: list[str] = []
    """The lab router this robot's router joins, e.g. ``["ws/192.168.1.2:7448"]`` (docs/lab.md).
    Needs access_control; the protocol must be one the robot's router does not listen on."""
    config: str = ""
    """Extra Zenoh JSON5 config file merged into the router's."""


class Program(Section):
    """One of your own services (``[programs.<name>]``): a program in any language that
    `icefloe up` starts, supervises, restarts and stops like its own services. It gets the
    robot's name, router and credentials in ``ICEFLOE_*`` environment variables
    (`icefloe.launcher.program_environment`, docs/own-services.md)."""

    command: list[str]
    """The program and its arguments, e.g. ``["{python}", "follower.py"]`` or ``["./drive.sh"]``.
    A relative path is relative to ``cwd``; a bare name (``bash``) is looked up in PATH."""
    env: dict[str, str] = {}
    """Environment variables of its own, besides the ``ICEFLOE_*`` ones."""
    cwd: str = ""
    """Its working folder ("" = the folder of the config file that defines it)."""
    restart: bool = True
    """Start it again when it exits, with the same back-off as icefloe's services (false:
    once it has exited, it stays stopped; the rest of the robot runs on)."""


RESERVED_NAMES = {*ALL_SERVICES, *OPTIONAL_SERVICES, "router", "viz", "up", "cli"}
"""Names a program may not have: icefloe's own processes."""


class RobotConfig(Section):
    name: str = "sim"
    run_dir: str = ""
    """Runtime folder for sockets, pseudo-terminals and the router's password file, private to
    the services' user ("" = $XDG_RUNTIME_DIR/icefloe/<name>, or <tmp>/icefloe-<uid>/<name>)."""
    services: list[str] = msgspec.field(default_factory=lambda: list(ALL_SERVICES))
    """Services `icefloe up` starts (besides the router), in order; missing ones are skipped.
    May name `programs` to place them; programs not named start after the services."""
    programs: dict[str, Program] = {}
    """Your own services, ``[programs.<name>]`` (see `Program`)."""
    board: Board = Board()
    geometry: Geometry = Geometry()
    hwbridge: Hwbridge = Hwbridge()
    car: Car = Car()
    camera: Camera = Camera()
    extloc: Extloc = Extloc()
    overhead: Overhead = Overhead()
    power: Power = Power()
    display: Display = Display()
    odometry: Odometry = Odometry()
    localizer: Localizer = Localizer()
    mapper: Mapper = Mapper()
    slam: Slam = Slam()
    sim: Sim = Sim()
    planner: Planner = Planner()
    follower: Follower = Follower()
    ros2: Ros2 = Ros2()
    judge: Judge = Judge()
    webapi: Webapi = Webapi()
    lab: Lab = Lab()
    zenoh: Zenoh = Zenoh()
    source: str = ""
    """The file this config was read from (filled in by `load`)."""

    @property
    def runtime_dir(self) -> Path:
        return Path(self.run_dir) if self.run_dir else default_run_dir(self.name)


def default_run_dir(name: str) -> Path:
    """``$XDG_RUNTIME_DIR/icefloe/<name>``, or ``<tmp>/icefloe-<uid>/<name>`` without one."""
    xdg = os.environ.get("XDG_RUNTIME_DIR", "")
    if xdg and os.path.isabs(xdg):
        return Path(xdg) / "icefloe" / name
    return Path(tempfile.gettempdir()) / f"icefloe-{os.getuid()}" / name


def private_dir(path: Path) -> Path:
    """Make ``path`` (and the folders it needs) a folder only this user may enter (0700).

    Refuses (`ConfigError`) a symlink, a file, or a folder that belongs to another user: in a
    shared ``/tmp`` someone else could have made it first to read or swap what we put there.
    The parent of the default folder under ``<tmp>`` is checked the same way.
    """
    if not path.is_absolute():
        path = path.absolute()
    shared_tmp = Path(tempfile.gettempdir())
    if path.parent.parent == shared_tmp and path.parent.name.startswith("icefloe-"):
        private_dir(path.parent)  # <tmp>/icefloe-<uid>: ours too, or someone could swap <name>
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
        st = os.lstat(path)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot make the runtime folder: {exc.strerror}") from None
    if stat.S_ISLNK(st.st_mode) or not stat.S_ISDIR(st.st_mode):
        raise ConfigError(f"{path}: the runtime folder is a symlink or not a folder; remove it or set run_dir")
    if st.st_uid != os.getuid():
        raise ConfigError(f"{path}: the runtime folder belongs to user {st.st_uid}, not to this user "
                          f"({os.getuid()}); remove it or set run_dir")
    if st.st_mode & 0o077:
        os.chmod(path, 0o700)
    return path


SECRET_FIELDS = ("password",)


def printable(config: RobotConfig) -> dict[str, Any]:
    """The config as plain data for printing, with the password replaced by ``"***"``."""
    data = msgspec.to_builtins(config)
    for field in SECRET_FIELDS:
        if data["zenoh"].get(field):
            data["zenoh"][field] = "***"
    return data


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def read_toml(path: Path, what: str = "config file") -> dict[str, Any]:
    """A TOML file as a dict; `ConfigError` names the file and what was wrong with it."""
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such {what}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None


def _anchor_programs(data: dict[str, Any], folder: Path) -> None:
    """Give each ``[programs.<name>]`` of one file that file's folder as its ``cwd`` (or resolve
    its relative ``cwd`` there), before files are merged: the folder of the file that defines it."""
    programs = data.get("programs")
    if not isinstance(programs, dict):
        return  # not a table: the type check after merging names the problem
    for program in programs.values():
        if isinstance(program, dict) and isinstance(program.get("cwd", ""), str):
            cwd = Path(program.get("cwd", "")).expanduser()
            program["cwd"] = str(cwd if cwd.is_absolute() else folder / cwd)


CALIBRATION_KEYS = (("camera", "calibration"), ("overhead", "calibration"))
"""Files a config names that belong beside it: a relative path is relative to the file that sets it."""


def _anchor_files(data: dict[str, Any], folder: Path) -> None:
    """Make each relative `CALIBRATION_KEYS` path of one file relative to that file's folder, before
    files are merged (the shipped ``sim.toml`` names ``sim.camera.yaml`` beside it)."""
    for table, key in CALIBRATION_KEYS:
        section = data.get(table)
        value = section.get(key) if isinstance(section, dict) else None
        if isinstance(value, str) and value and "{" not in value:
            path = Path(value).expanduser()
            section[key] = str(path if path.is_absolute() else folder / path)


def _read(path: Path, seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    if path in seen:
        raise ConfigError(f"{path}: `extends` loops back to itself")
    data = read_toml(path)
    _anchor_programs(data, path.parent)
    _anchor_files(data, path.parent)
    parent = data.pop("extends", None)
    if parent is None:
        return data
    if not isinstance(parent, str):
        raise ConfigError(f"{path}: extends: expected a file name")
    base_path = path.parent / parent
    if base_path.resolve() == path or not base_path.exists():
        if paths.is_path(name := parent.removesuffix(".toml")):
            raise ConfigError(f"{path}: extends: no such file {base_path}")
        try:
            base_path = paths.find("robots", name, "robot config", skip=path)  # your own, else the shipped one
        except ConfigError as exc:
            raise ConfigError(f"{path}: extends: neither {base_path} nor {exc}") from None
    return _merge(_read(base_path.resolve(), (*seen, path)), data)


def _expand(value: Any, names: dict[str, str]) -> Any:
    if isinstance(value, str):
        for placeholder, text in names.items():
            value = value.replace(f"{{{placeholder}}}", text)
        return value
    if isinstance(value, list):
        return [_expand(v, names) for v in value]
    if isinstance(value, dict):
        return {k: _expand(v, names) for k, v in value.items()}
    return value


def _field_path(message: str) -> tuple[str, str]:
    """Turn msgspec's "... - at `$.hwbridge.rate_hz`" into ("hwbridge.rate_hz", "...")."""
    text, sep, where = message.rpartition(" - at `$")
    if not sep:
        return "", message
    return where.rstrip("`").lstrip("."), text


def _convert(value: Any, type_: type, where: str) -> None:
    """msgspec.convert, its error's path starting at ``where`` (a table msgspec cannot name)."""
    try:
        msgspec.convert(value, type_)
    except msgspec.ValidationError as exc:
        text, sep, at = str(exc).rpartition(" - at `$")
        raise msgspec.ValidationError(f"{text} - at `$.{where}{at}" if sep else f"{exc} - at `$.{where}`") from None


def field_error(source: str, exc: msgspec.ValidationError) -> str:
    """``"<source>: <key path>: <problem>"`` from a msgspec validation error (for TOML files)."""
    where, text = _field_path(str(exc))
    if "unknown field" in text and where:
        where = f"[{where}]"
    return f"{source}: {where + ': ' if where else ''}{text}"


def parse(data: dict[str, Any], source: str = "<config>", *, credentials: bool = True) -> RobotConfig:
    """Typed config from a TOML-shaped dict; `ConfigError` names the source and the key.
    ``credentials=False``: leave the robot's credentials file unread (a tool that only reads the
    robot, run by a user who may not read the file: `icefloe doctor` as ``pi``)."""
    try:
        if isinstance(programs := data.get("programs"), dict):
            for name, program in programs.items():  # one by one: an error names the program
                _convert(program, Program, f"programs.{name}")
        config = msgspec.convert(data, RobotConfig)
    except msgspec.ValidationError as exc:
        raise ConfigError(field_error(source, exc)) from None
    if not config.name or any(c in config.name for c in "/*$#? "):
        raise ConfigError(f"{source}: name: {config.name!r} is not a usable robot name")
    check_programs(config, source)
    check_car(config, source)
    check_lab(config.zenoh, config.zenoh.listen, source)
    run_dir = str(config.runtime_dir)
    expanded = _expand(msgspec.to_builtins(config), {"run_dir": run_dir, "name": config.name,
                                                     "python": sys.executable})
    expanded["source"] = source
    zenoh = expanded["zenoh"]
    if credentials and zenoh["credentials"] and not zenoh["user"] and Path(zenoh["credentials"]).expanduser().exists():
        from .credentials import read

        creds = read(zenoh["credentials"])
        zenoh["user"], zenoh["password"] = creds.user, creds.password
    return msgspec.convert(expanded, RobotConfig)


def check_programs(config: RobotConfig, source: str) -> None:
    """`ConfigError` for a program that could never run: a name that is not a plain name or is
    one of icefloe's own processes, or no command."""
    for name, program in config.programs.items():
        if not paths.NAME.fullmatch(name) or name in RESERVED_NAMES:
            why = "is icefloe's own" if name in RESERVED_NAMES else "is not a plain name (letters, digits, _ . -)"
            raise ConfigError(f"{source}: [programs.{name}]: the name {name!r} {why}")
        if not program.command or not program.command[0]:
            raise ConfigError(f"{source}: programs.{name}.command: give the program to run, "
                              'e.g. ["{python}", "my_service.py"]')


def check_car(config: RobotConfig, source: str) -> None:
    """`ConfigError` for a car whose tightest turn would run its inner rear wheel backwards: a
    car's turning centre lies beyond its rear wheels, wheelbase / tan(max_steer) >= track / 2."""
    car, half_track = config.car, config.geometry.track / 2
    tightest = car.wheelbase / math.tan(car.max_steer)
    if tightest < half_track:
        most = math.atan(car.wheelbase / half_track)
        raise ConfigError(f"{source}: car.max_steer: {car.max_steer:g} rad turns about a point "
                          f"{tightest:.3f} m from the rear axle's centre, inside the wheels ({half_track:g} m "
                          f"each side): a car's inner wheel would run backwards; at most {most:.3f} rad for "
                          f"wheelbase {car.wheelbase:g} m")


def protocol(endpoint: str) -> str:
    """``"ws/10.0.0.2:7448"`` -> ``"ws"``."""
    return endpoint.split("/", 1)[0]


def check_lab(zenoh: Zenoh, listen: list[str], source: str) -> None:
    """`ConfigError` unless ``[zenoh] lab`` can work: access control on, and a protocol the robot's
    router does not listen on (that is how the router knows its lab link: deploy/zenoh/acl/lab-link.json5)."""
    if not zenoh.lab:
        return
    if not zenoh.access_control:
        raise ConfigError(f"{source}: zenoh.lab needs zenoh.access_control = true: the robot's router "
                          "logs in to the lab router with the robot's credentials")
    if bad := [e for e in zenoh.lab if "/" not in e]:
        raise ConfigError(f"{source}: zenoh.lab: {bad[0]!r} is not a Zenoh endpoint (e.g. 'ws/192.168.1.2:7448')")
    if clash := {protocol(e) for e in zenoh.lab} & {protocol(e) for e in listen}:
        p = sorted(clash)[0]
        raise ConfigError(f"{source}: zenoh.lab uses {p}, which this robot's router also listens on, so it "
                          f"could not tell its lab link from a laptop: give the lab router another "
                          f"protocol, e.g. ws/<lab machine>:7448 (docs/lab.md)")


def find(name_or_path: str | os.PathLike[str] | None = None) -> Path:
    """The file of a robot config: ``None`` = the simulated robot, a name is looked up
    (`icefloe.paths`), a path (with a ``/`` or ending in ``.toml``) is that file."""
    return paths.find("robots", DEFAULT_ROBOT if name_or_path is None else name_or_path, "robot config")


def load(name_or_path: str | os.PathLike[str] | None = None, *, credentials: bool = True) -> RobotConfig:
    """Load a robot config by name or path (``None`` = the simulated robot ``sim``); ``credentials``
    as `parse`."""
    p = find(name_or_path)
    return parse(_read(p.resolve()), str(p), credentials=credentials)


def robot_info(config: RobotConfig) -> m.RobotInfo:
    """What the robot is, as the ``info`` query answers it (the info service), and as a client
    takes it from the config while that service does not answer."""
    return m.RobotInfo(
        name=config.name,
        board=config.board.kind,
        backend=config.board.backend,
        wheel_diameter=config.geometry.wheel_diameter,
        track=config.geometry.track,
        ticks_per_rev=config.geometry.ticks_per_rev,
        max_wheel_speed=config.hwbridge.max_wheel_speed,
        wheelbase=config.car.wheelbase,
        max_steer=config.car.max_steer,
    )
