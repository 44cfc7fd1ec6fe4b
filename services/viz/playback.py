"""``icefloe viz FILE.mcap``: the live view's layout and drawing, fed from a recording.

The messages of the file go through the same `RobotLogger` calls as live ones (``app.STREAMS``),
each at its own ``stamp`` on the ``stamp`` timeline (``oled/frame``, which has none, at the time
the recorder received it), so the time slider scrubs through the recorded session. Unlike the
live view nothing is thinned out: a file is looked at after the fact, every sample is worth a
point. Raw channels (keys outside the key table, payloads that did not decode) are not drawn.
A recording holds no query answers, so the occupancy grid drawn is the one of the config's world
file (`icefloe.grid.of_robot`), as are the landmarks and obstacles, and the car on ``car/state``
has the config's wheelbase and track.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Sequence
from pathlib import Path

from icefloe.bag import Bag
from icefloe.bag.channels import decode
from icefloe.config import RobotConfig
from icefloe.errors import BadRecording
from icefloe.logs import LimitedLog
from icefloe.schemas import keys

from .app import STREAMS, car_size, open_recording, world_grid, world_markers, world_obstacles
from .logging_rr import RobotLogger
from .options import VizOptions

log = logging.getLogger("icefloe.viz")


def robots_in(bag: Bag, only: str | None = None) -> list[str]:
    """The robots whose keys the recording holds (just ``only`` if given and present)."""
    robots = sorted({keys.split(c.key)[0] for c in bag.channels() if keys.topic_of(c.key) is not None})
    return [r for r in robots if r == only] if only else robots


def show(bag: Bag, config: RobotConfig, options: VizOptions) -> int:
    """Log every drawable message of ``bag`` to the sink ``options`` name; returns the count."""
    robots = robots_in(bag, options.robot)
    if not robots:
        which = f" of robot {options.robot!r}" if options.robot else ""
        raise BadRecording(f"{bag.files[0].path}: no icefloe keys{which} to show")
    rec, _viewer = open_recording(options, robots, config.runtime_dir)
    markers, obstacles = world_markers(config, log), world_obstacles(config)
    grid = world_grid(config, log) if obstacles else None  # a recording holds no queries: the world file's
    loggers: dict[str, RobotLogger] = {}
    for robot in robots:
        logger = loggers[robot] = RobotLogger(rec, robot, capture_width=config.camera.width,
                                              car_size=car_size(config))
        logger.setup()
        logger.landmark_map(markers)
        logger.obstacles(obstacles)
        if grid is not None:
            logger.world_grid(grid)
    streams = {s.topic.name: s for s in STREAMS}
    warn = LimitedLog(log)
    shown = 0
    try:
        for entry in bag.entries():
            channel = entry.channel
            if channel.form == "raw" or channel.refused:
                continue
            robot, name = keys.split(channel.key)
            logger, stream = loggers.get(robot), streams.get(name)
            if logger is None or stream is None:
                continue
            try:
                message = decode(channel, entry.data)
                if stream.topic is keys.OLED_FRAME:
                    logger.oled(message, received_ns=entry.log_time)  # type: ignore[arg-type]
                else:
                    stream.handler(logger, message)
                shown += 1
            except Exception as exc:  # a message that cannot be drawn must not stop the others
                warn.warning("not shown", "%s: not shown: %s", channel.key, exc)
    finally:
        rec.flush()
        if not options.serve:
            rec.disconnect()
    if options.serve:  # the server lives in this process: keep it up for the viewers
        with contextlib.suppress(KeyboardInterrupt, asyncio.CancelledError):
            asyncio.run(asyncio.sleep(options.duration or float("inf")))
        rec.disconnect()
    return shown


def show_files(paths: Sequence[str | Path], config: RobotConfig, options: VizOptions) -> int:
    """``icefloe viz FILE.mcap``: exit status 0, after telling what was shown."""
    bag = Bag(paths)
    shown = show(bag, config, options)
    where = f"saved to {options.save}" if options.save else "sent to the viewer"
    print(f"viz: {shown} messages of {', '.join(str(s.path) for s in bag.files)} {where}")
    return 0
