"""Where overhead pictures come from, chosen by ``overhead.source``: the sources of
`icefloe.vision.sources` (V4L2/USB, picamera2, files), and ``"sim"``, which renders the lab's
robots at their ``sim/truth`` (`SimOverheadSource`)."""

from __future__ import annotations

import threading
import time

import numpy as np

from icefloe.config import Overhead, RobotConfig
from icefloe.schemas import messages as m
from icefloe.vision.geometry import Intrinsics
from icefloe.vision.overhead import CameraPose
from icefloe.vision.sources import Paced, Source, open_source


def sim_camera_pose(overhead: Overhead) -> CameraPose:
    """Where the simulated camera truly hangs (``overhead.sim_*``): the localizer does not know it."""
    return CameraPose.looking_down(overhead.sim_x, overhead.sim_y, overhead.sim_z, overhead.sim_yaw,
                                   overhead.sim_tilt)


class SimOverheadSource:
    """Frames of the simulated overhead camera: every robot at its latest ``sim/truth``
    (`set_truth`); a robot whose simulator has not spoken yet is not in the picture."""

    def __init__(self, overhead: Overhead, robots: list[RobotConfig]) -> None:
        from icefloe.sim.overhead import OverheadRenderer  # the simulator only where it is used
        from icefloe.worldmap import load_world

        self.renderer = OverheadRenderer(load_world(overhead.world),
                                         Intrinsics.nominal(overhead.focal_px, overhead.width, overhead.height),
                                         sim_camera_pose(overhead), overhead.dictionary,
                                         seed=overhead.sim_seed, noise=overhead.sim_noise)
        self.robots = {r.name: r.extloc for r in robots}
        self.pace = Paced(overhead.fps)
        self._truths: dict[str, m.Truth] = {}
        self._lock = threading.Lock()

    def set_truth(self, robot: str, truth: m.Truth) -> None:
        if robot in self.robots:
            with self._lock:
                self._truths[robot] = truth

    def views(self) -> list:
        from icefloe.sim.overhead import RobotView

        with self._lock:
            truths = dict(self._truths)
        return [RobotView(self.robots[name].marker_id, self.robots[name].marker_size, self.robots[name].marker_height,
                          t.x, t.y, t.theta) for name, t in truths.items()]

    def read(self) -> tuple[int, np.ndarray]:
        self.pace.wait()
        stamp = time.time_ns()  # the robots as they are now: the frame's time
        return stamp, self.renderer.render(self.views())

    def close(self) -> None:
        pass


def open_overhead(overhead: Overhead, robots: list[RobotConfig]) -> Source:
    """The source named by ``overhead.source``; `SourceError` if it cannot be opened now."""
    return open_source(overhead.source, overhead.width, overhead.height, overhead.fps, setting="overhead.source",
                       sim=lambda: SimOverheadSource(overhead, robots))
