"""The robot camera's sources: those of `icefloe.vision.sources`, chosen by ``camera.source``, and
the simulated camera, which renders the simulated world from the robot's true pose (``sim/truth``)."""

from __future__ import annotations

import threading

import numpy as np

from icefloe.config import RobotConfig
from icefloe.schemas import messages as m
from icefloe.vision.sources import Paced, Source, SourceError, open_source


class SimSource:
    """Frames rendered from the latest true pose, which the service hands over with `set_truth`."""

    def __init__(self, config: RobotConfig) -> None:
        from icefloe.sim.camera import CameraRenderer  # the simulator only where it is used

        self.renderer = CameraRenderer.of_robot(config)
        self.pace = Paced(config.camera.fps)
        self._truth: m.Truth | None = None
        self._lock = threading.Lock()

    def set_truth(self, truth: m.Truth) -> None:
        with self._lock:
            self._truth = truth

    def read(self) -> tuple[int, np.ndarray]:
        self.pace.wait()
        with self._lock:
            truth = self._truth
        if truth is None:
            raise SourceError("no sim/truth yet: is the simulator running?")
        image, _ = self.renderer.render(truth.x, truth.y, truth.theta)
        return truth.stamp, image  # the frame shows the world at the truth's time

    def close(self) -> None:
        pass


def open_camera(config: RobotConfig) -> Source:
    """The source named by ``camera.source``; `SourceError` if it cannot be opened now."""
    cam = config.camera
    return open_source(cam.source, cam.width, cam.height, cam.fps, setting="camera.source",
                       sim=lambda: SimSource(config))
