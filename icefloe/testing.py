"""Helpers for testing your own services, as icefloe tests its own (docs/own-services.md).

    async with local_bus() as config:         # a Zenoh router in this process, on a free port
        task = asyncio.create_task(my_service.main(config))
        async with Node("tester", config) as node:
            ...                                # publish what it reads, check what it publishes

Two sessions in one process and a router between them: the real bus, with no `icefloe up`
and no robot. `icefloe new-service` writes a test that uses it.

A localizer, a map maker or SLAM can be tested before (or without) the camera service:
`TruthCamera` makes the sightings the camera would make from the simulator's true pose, and
`play_camera` publishes them on ``camera/landmarks`` as ``sim/truth`` comes.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import random
import socket
import tempfile
from collections.abc import AsyncIterator, Awaitable, Callable

import msgspec
import zenoh

from . import config as config_mod
from .angles import wrap_angle
from .config import RobotConfig
from .runtime import Node, zenoh_config
from .schemas import keys
from .schemas import messages as m
from .worldmap import load_world


def free_port() -> int:
    """A TCP port nobody listens on now, on this machine."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.asynccontextmanager
async def local_bus(name: str = "test", config: RobotConfig | None = None) -> AsyncIterator[RobotConfig]:
    """A robot config (``config``, default: the simulated robot) named ``name`` whose bus is a
    Zenoh router in this process, listening on a free local port; closed on exit."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    base = config or config_mod.load()
    with tempfile.TemporaryDirectory(prefix="icefloe-test-") as run_dir:
        robot = msgspec.structs.replace(
            base, name=name, run_dir=run_dir,
            zenoh=msgspec.structs.replace(base.zenoh, listen=[endpoint], connect=[endpoint], access_control=False,
                                          credentials="", user="", password=""))
        router = await asyncio.to_thread(zenoh.open, zenoh_config(robot, mode="router", listen=[endpoint]))
        try:
            yield robot
        finally:
            router.close()


async def eventually(check: Callable[[], Awaitable[bool] | bool], timeout: float = 10.0,
                     interval: float = 0.05) -> None:
    """Wait until ``check()`` is true (it may be async); AssertionError after ``timeout`` s.
    For what arrives over the bus: messages take a moment, more on a busy machine."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        result = check()
        if asyncio.iscoroutine(result) or isinstance(result, Awaitable):
            result = await result
        if result:
            return
        if loop.time() > deadline:
            raise AssertionError(f"not true within {timeout} s: {getattr(check, '__name__', check)}")
        await asyncio.sleep(interval)


UNKNOWN_ID = 49
"""The marker id `TruthCamera` reports when asked for sightings of markers not in the map."""


def steer_round(corners: list[tuple[float, float]], corner: int, pose: m.Truth, speed: float = 0.2,
                turn: float = 1.0, reached: float = 0.05) -> tuple[int, m.Twist | None]:
    """One step of driving round ``corners`` (world m) on the true pose: the corner to make for next
    (``corner`` counts the sides driven; one more once within ``reached`` m of it), and the twist
    (m/s, rad/s): turn on the spot (at most ``turn``) while the heading is off by more than 0.15 rad,
    else drive at ``speed`` steering onto it; None on the step a corner is reached. Steering on the
    truth makes every run drive the same path, whatever the wheels and however busy the machine
    (bench/slam.py, bench/sim_profiles.py, tests/test_slam_rendered.py)."""
    gx, gy = corners[corner % len(corners)]
    if math.hypot(gx - pose.x, gy - pose.y) < reached:
        return corner + 1, None
    err = wrap_angle(math.atan2(gy - pose.y, gx - pose.x) - pose.theta)
    if abs(err) > 0.15:
        return corner, m.Twist(v=0.0, w=max(-turn, min(turn, 3.0 * err)))
    return corner, m.Twist(v=speed, w=2.0 * err)


class TruthCamera:
    """A fake of the camera service: what it would report from a true pose (``sim/truth``).

    Each marker of the map ``localizer.world`` that the camera could read from there (within
    its field of view, from ``camera.width`` and ``camera.focal_px``; farther than 0.2 m and
    nearer than ``max_range``; seen at most ``max_incidence`` off head-on) becomes a sighting:
    range and bearing with seeded Gaussian noise (``sigma_range`` m plus ``sigma_range_rel`` of the
    range, ``sigma_bearing`` rad). ``outlier_rate`` of the sightings are made gross errors (a
    misdetection: 1.3 to 2 times the range, 0.2 to 0.5 rad off), and ``unknown_rate`` of the frames
    get a sighting of `UNKNOWN_ID`, which no map holds. Counts what it made up: `sightings`,
    `injected_outliers`."""

    def __init__(self, config: RobotConfig, rng: random.Random, *, max_range: float = 3.0,
                 max_incidence: float = math.radians(70), sigma_range: float = 0.02, sigma_range_rel: float = 0.01,
                 sigma_bearing: float = 0.01, outlier_rate: float = 0.0, unknown_rate: float = 0.0) -> None:
        self.markers = load_world(config.localizer.world).markers
        c = config.camera
        self.half_fov = math.atan2(c.width / 2, c.focal_px)
        self.rng = rng
        self.max_range, self.max_incidence = max_range, max_incidence
        self.sigma_range, self.sigma_range_rel, self.sigma_bearing = sigma_range, sigma_range_rel, sigma_bearing
        self.outlier_rate, self.unknown_rate = outlier_rate, unknown_rate
        self.sightings = 0
        """Sightings made so far."""
        self.injected_outliers = 0
        """Of those, made gross errors."""

    def frame(self, truth: tuple[float, float, float], stamp: int) -> m.Landmarks:
        """The sightings from the true pose ``truth`` (x m, y m, theta rad), stamped ``stamp`` ns."""
        x, y, th = truth
        rng = self.rng
        seen = []
        for mk in self.markers:
            r = math.hypot(mk.x - x, mk.y - y)
            b = wrap_angle(math.atan2(mk.y - y, mk.x - x) - th)
            facing = abs(wrap_angle(math.atan2(y - mk.y, x - mk.x) - mk.yaw))  # 0 = seen head-on
            if abs(b) > self.half_fov or not 0.2 < r < self.max_range or facing > self.max_incidence:
                continue
            r += rng.gauss(0.0, math.hypot(self.sigma_range, self.sigma_range_rel * r))
            b = wrap_angle(b + rng.gauss(0.0, self.sigma_bearing))
            if rng.random() < self.outlier_rate:
                self.injected_outliers += 1
                r, b = r * rng.uniform(1.3, 2.0), wrap_angle(b + rng.choice((-1, 1)) * rng.uniform(0.2, 0.5))
            seen.append(m.Landmark(id=mk.id, range=r, bearing=b))
        if rng.random() < self.unknown_rate:
            seen.append(m.Landmark(id=UNKNOWN_ID, range=1.0, bearing=0.0))
        self.sightings += len(seen)
        return m.Landmarks(stamp=stamp, landmarks=seen)


async def play_camera(node: Node, camera: TruthCamera, *, every: int = 3,
                      on_truth: Callable[[m.Truth, m.Landmarks | None], object] | None = None) -> None:
    """Stand in for the camera service, until cancelled: every ``every``-th ``sim/truth`` sample
    (the simulator's 50 Hz: about 17 frames a second) becomes ``camera``'s sightings from it, put
    on ``camera/landmarks``. ``on_truth(truth, frame)`` sees every sample, and the frame made of
    it (None for the others)."""
    landmarks = node.publisher(keys.LANDMARKS)
    count = 0
    async for truth in node.subscribe(keys.TRUTH, latest=False):
        count += 1
        frame = camera.frame((truth.x, truth.y, truth.theta), truth.stamp) if count % every == 0 else None
        if frame is not None:
            landmarks.put(frame)
        if on_truth is not None:
            on_truth(truth, frame)
