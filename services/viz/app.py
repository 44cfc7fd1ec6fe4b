"""The viz service: follow robots on the bus and stream them to a Rerun viewer.

Data flow, and where it may be dropped (always here on the laptop, never on the robot)::

    robot publishers --Zenoh--> Subscription (latest value) --> Decimator --> RobotLogger --> Rerun sink
         (drop if the link        (keeps only the newest      (e.g. 100 Hz     (rr.log:        (viewer, server
          is congested)            sample: we never queue)     -> 20 Hz)        never blocks)   or .rrd file)

* Robot publishers use congestion control DROP, and our subscriptions keep only
  the newest sample, so a slow laptop never pushes back on the robot.
* ``--serve`` holds the recording in a gRPC server in this process with a
  memory limit: when viewers are slow or gone, the oldest data is dropped there.
* The occupancy grid (``map/grid``) is a query, not a stream: viz asks each robot for it every
  `GRID_POLL_S` and draws it only when the answer differs from the one drawn (it is large and
  static). A robot without a grid service simply has no grid on its map.
* Without ``--robot``, robots are found by their liveliness tokens
  (``icefloe/*/alive/*``) and each appears under ``/robots/<name>`` in its own tab.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import rerun as rr

from icefloe.config import RobotConfig
from icefloe.errors import BadPayload, ConfigError, NotReachable
from icefloe.grid import Grid, of_robot
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.schemas.keys import Topic
from icefloe.worldmap import Rectangle, load_world

from .blueprint import blueprint
from .decimate import Decimator
from .logging_rr import RobotLogger
from .options import VizOptions
from .viewer import Viewer

APP_ID = "icefloe"
DISCOVERY_INTERVAL_S = 1.0
GRID_POLL_S = 5.0
"""How often viz asks a robot for its occupancy grid (``map/grid``); it is drawn only when it changed."""
GRID_TIMEOUT_S = 10.0
PROBLEM_CHARS = 300


@dataclass(frozen=True)
class Stream:
    """One bus topic shown in the viewer, and how much of it."""

    topic: Topic
    handler: Callable[[RobotLogger, Any], None]
    rate_hz: float = 0.0
    """At most this many messages per second reach the viewer (0 = all of them)."""
    latest: bool = True
    """Keep only the newest sample (state); False = keep every message in order (logs)."""


STREAMS = (
    Stream(keys.WHEELS, RobotLogger.wheels, rate_hz=20),  # 50 Hz on the bus
    Stream(keys.ODOM_POSE, RobotLogger.odom, rate_hz=20),
    Stream(keys.LOC_POSE, RobotLogger.loc, rate_hz=20),
    Stream(keys.EXTLOC_POSE, RobotLogger.extloc, rate_hz=20),  # the lab's overhead camera (docs/extloc.md)
    Stream(keys.TRUTH, RobotLogger.truth, rate_hz=20),  # 50 Hz on the bus
    Stream(keys.CAR_STATE, RobotLogger.car, rate_hz=20),  # 50 Hz while the car moves, 1 Hz standing
    Stream(keys.SLAM_POSE, RobotLogger.slam, rate_hz=20),
    Stream(keys.SLAM_MAP, RobotLogger.slam_map, rate_hz=2),
    Stream(keys.MAP_LANDMARKS, RobotLogger.reference_map, rate_hz=2),
    Stream(keys.LANDMARKS, RobotLogger.landmarks, rate_hz=10),
    Stream(keys.NAV_PATH, RobotLogger.path),  # a few per run
    Stream(keys.NAV_STATUS, RobotLogger.nav_status),  # logged only when the state changes
    Stream(keys.JUDGE_STATE, RobotLogger.judge, rate_hz=5),  # the lap judge (docs/judge.md)
    Stream(keys.JUDGE_LAP, RobotLogger.judge_lap, latest=False),  # once a lap
    Stream(keys.IMAGE, RobotLogger.image, rate_hz=10),
    Stream(keys.BATTERY, RobotLogger.battery),
    Stream(keys.HW_BATTERY, RobotLogger.battery_raw, rate_hz=5),
    Stream(keys.LOOP, RobotLogger.loop),
    Stream(keys.OLED_FRAME, RobotLogger.oled),  # no stamp; a few Hz at most
    Stream(keys.LOG, RobotLogger.log, latest=False),  # every line matters
)


def car_size(config: RobotConfig) -> tuple[float, float]:
    """(wheelbase, track) m of the virtual car drawn, from a robot config."""
    return config.car.wheelbase, config.geometry.track


def world_markers(config: RobotConfig, log: logging.Logger) -> list[tuple[int, float, float, float, float]]:
    """The landmark map of the config's world file as (id, x, y, size, yaw); [] if it cannot be read."""
    try:
        world = load_world(config.localizer.world)
    except ConfigError as exc:  # a missing or bad world file costs the map its markers, nothing more
        log.warning("the map shows no landmarks: %s", exc)
        return []
    return [(mk.id, mk.x, mk.y, mk.size, mk.yaw) for mk in world.markers]


def world_obstacles(config: RobotConfig) -> list[Rectangle]:
    """Footprints of the config's world file's obstacles; [] if it cannot be read (`world_markers` says why)."""
    try:
        world = load_world(config.localizer.world)
    except ConfigError:
        return []
    return [o.rectangle() for o in world.obstacles]


def world_grid(config: RobotConfig, log: logging.Logger) -> Grid | None:
    """The occupancy grid of the config's world, as the grid service would serve it (for a
    recording, which holds no queries); None, and why, if it cannot be made."""
    try:
        return of_robot(config)
    except ConfigError as exc:
        log.warning("the map shows no occupancy grid: %s", exc)
        return None


def open_recording(options: VizOptions, robots: list[str], run_dir: Path) -> tuple[rr.RecordingStream, Viewer | None]:
    """A Rerun recording with the sink the options ask for, and the default blueprint; and the
    native viewer it streams to (None with ``--save`` or ``--serve``)."""
    viewer = None
    if not (options.save or options.serve):  # first: without a window there is no recording to make
        viewer = Viewer(options.grpc_port, options.memory_limit, run_dir / "rerun-viewer.log")
    rec = rr.RecordingStream(APP_ID)
    layout = blueprint(robots)
    if options.save:
        rec.save(options.save, default_blueprint=layout)
    elif options.serve:
        url = rec.serve_grpc(grpc_port=options.grpc_port, default_blueprint=layout,
                             server_memory_limit=options.memory_limit)
        rr.serve_web_viewer(web_port=options.web_port, open_browser=False, connect_to=url)
        print(f"viz: web viewer at http://localhost:{options.web_port}/?url={url}\n"
              f"viz: native viewer: rerun {url}", flush=True)
    elif viewer is not None:
        rec.connect_grpc(viewer.url, default_blueprint=layout)
    return rec, viewer


class Shown:
    """The robots being shown: one `RobotLogger` and one task per stream for each."""

    def __init__(self, node: Node, rec: rr.RecordingStream, tasks: asyncio.TaskGroup) -> None:
        self.node = node
        self.rec = rec
        self.loggers: dict[str, RobotLogger] = {}
        self._tasks = tasks
        self._markers = world_markers(node.config, node.log)
        self._obstacles = world_obstacles(node.config)

    def add(self, robot: str) -> None:
        """Start showing ``robot`` (nothing happens if it is shown already)."""
        if robot in self.loggers:
            return
        logger = RobotLogger(self.rec, robot, capture_width=self.node.config.camera.width,
                             car_size=car_size(self.node.config))
        logger.setup()
        logger.landmark_map(self._markers)
        logger.obstacles(self._obstacles)
        self.loggers[robot] = logger
        for stream in STREAMS:
            self._tasks.create_task(self._follow(logger, stream))
        self._tasks.create_task(self._follow_grid(logger))
        self._tasks.create_task(self._car_size(logger))
        # A new robot gets its own tab; the layout is sent again with it.
        self.rec.send_blueprint(blueprint(list(self.loggers)))
        self.node.log.info("showing robot %r", robot)

    async def _follow(self, logger: RobotLogger, stream: Stream) -> None:
        sub = self.node.subscribe(stream.topic, robot=logger.robot, latest=stream.latest, maxsize=256)
        decimator = Decimator(stream.rate_hz)
        async for msg in sub:
            stamp = getattr(msg, "stamp", None)
            if stamp is not None and not decimator.keep(stamp):
                continue
            try:
                stream.handler(logger, msg)
            except Exception as exc:  # a message that decodes but cannot be drawn must not stop the viewer
                key = keys.key(logger.robot, stream.topic)
                self.node.limited.warning(f"{logger.robot}/{stream.topic.name}", "%s: dropped: %s", key, exc)

    async def _car_size(self, logger: RobotLogger) -> None:
        """The robot's own car (its ``info``: wheelbase, track), once it answers; until then, and for a
        robot that never does, the config's."""
        while True:
            try:
                info = await self.node.query(keys.INFO, m.Stop(), robot=logger.robot, timeout=GRID_TIMEOUT_S)
            except NotReachable:
                await asyncio.sleep(GRID_POLL_S)
                continue
            except BadPayload as exc:
                self.node.limited.warning(f"{logger.robot}/info", "%s", str(exc)[:PROBLEM_CHARS])
                return
            if info.wheelbase > 0 and info.track > 0 and math.isfinite(info.wheelbase + info.track):
                logger.car_size = (info.wheelbase, info.track)
            return

    async def _follow_grid(self, logger: RobotLogger) -> None:
        """Ask the robot for its occupancy grid now and then; draw it when it changed. A grid that
        cannot be drawn is named once (until another problem, or a good grid, comes)."""
        key = keys.key(logger.robot, keys.MAP_GRID)
        refused = ""
        while True:
            problem = ""
            try:
                grid = await self.node.query(keys.MAP_GRID, m.GridRequest(), robot=logger.robot,
                                             timeout=GRID_TIMEOUT_S)
                if logger.grid(grid):
                    self.node.log.info("%s: drew the occupancy grid of world %r, %d x %d cells of %.3f m", key,
                                       grid.world[:64], grid.width, grid.height, grid.resolution)
            except NotReachable:
                pass  # no grid service on this robot (yet): nothing to draw
            except BadPayload as exc:  # not an OccupancyGrid: the message names the key and field
                problem = f"{key}: dropped: {str(exc).removeprefix(key + ': ')}"
            except ValueError as exc:  # an OccupancyGrid that cannot be a grid (`grid_cells`)
                problem = f"{key}: dropped: {exc}"
            if problem and problem != refused:  # a student's error reply may be long: one line, not a page
                self.node.limited.warning(f"{logger.robot}/map/grid", "%s", problem[:PROBLEM_CHARS])
            refused = problem
            await asyncio.sleep(GRID_POLL_S)

    async def discover(self) -> None:
        """Add every robot that holds a liveliness token, now and whenever one appears."""
        while True:
            for token in await self.node.alive("*"):
                robot, name = keys.split(token)  # name is "alive/<service>"
                # A viewer's own token is not a robot (ours sits under the laptop config's name).
                if name.rsplit("/", 1)[-1] != "viz":
                    self.add(robot)
            await asyncio.sleep(DISCOVERY_INTERVAL_S)


class WindowClosed(Exception):
    """The native viewer we started has exited: the student closed its window."""


async def watch(window: Viewer, node: Node) -> None:
    """End viz when the viewer's window is closed (`icefloe up` does not restart a viz that ends so)."""
    while not window.closed():
        await asyncio.sleep(0.5)
    node.log.info("the viewer was closed; viz ends (`icefloe viz` opens it again)")
    raise WindowClosed


async def main(config: RobotConfig, options: VizOptions) -> None:
    """Show ``options.robot`` (or every robot found) until cancelled or ``options.duration`` is up."""
    robots = [options.robot] if options.robot else []
    rec, window = await asyncio.to_thread(open_recording, options, robots, config.runtime_dir)
    try:
        async with Node("viz", config) as node:
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(options.duration):
                    try:
                        async with asyncio.TaskGroup() as tasks:
                            shown = Shown(node, rec, tasks)
                            if options.robot:
                                shown.add(options.robot)
                            else:
                                tasks.create_task(shown.discover())
                            if window is not None:
                                tasks.create_task(watch(window, node))
                    except* WindowClosed:
                        pass
    finally:
        # Flush and close the sink even on SIGINT, so a recording ends with a complete file.
        try:
            rec.flush()
        except RuntimeError as exc:  # the viewer is gone (its window was closed): nothing left to send to
            logging.getLogger("icefloe.viz").info("not flushed: %s", exc)
        rec.disconnect()
