"""The robot camera's sources: those of `icefloe.vision.sources`, chosen by ``camera.source``, and
the simulated camera, which renders the simulated world from the robot's true pose (``sim/truth``)."""

from __future__ import annotations

import random
import sys
import threading
import time
from collections import deque
from collections.abc import Callable

import numpy as np

from icefloe.config import RobotConfig
from icefloe.schemas import messages as m
from icefloe.vision.sources import Paced, Source, SourceError, open_source


class SimSource:
    """Frames rendered from the latest true pose, which the service hands over with `set_truth`.

    In the ideal profile a frame is rendered at ``camera.fps`` and handed over at once, stamped
    with the true pose's time. In the realistic profile (`icefloe.sim.realism`) the camera's
    pipeline holds each frame for its latency (`Delivery`: some jitter, a frame now and then lost)
    and it is stamped when it arrives, as a real camera's source stamps it: late by that latency,
    which the service takes off again if its calibration measured it."""

    def __init__(self, config: RobotConfig, truth: Callable[[], m.Truth | None] | None = None) -> None:
        """``truth``: asked for the newest true pose at each frame (the service's `Latest` of
        ``sim/truth``: one decoded per frame, not each of the simulator's 50 a second); without it,
        the pose last handed over with `set_truth`."""
        from icefloe.sim import realism  # the simulator only where it is used
        from icefloe.sim.camera import CameraRenderer
        from icefloe.sim.sensor import Delivery

        picture = realism.picture(config)
        ideal = picture.plain and not (picture.latency_s or picture.latency_jitter_s or picture.drop_rate)
        seed = 1 if ideal else config.sim.seed or random.SystemRandom().randrange(1, 2**31)
        if not ideal and not config.sim.seed:
            print(f"sim camera: seed {seed} (sim.seed = {seed} repeats its light, noise and latency)", file=sys.stderr)
        self.renderer = CameraRenderer.of_robot(config, seed=seed)
        self.delivery = None if ideal else Delivery(picture, np.random.default_rng(seed + 1))
        self.pace = Paced(config.camera.fps)
        self._truth: m.Truth | None = None
        self._newest_truth = truth
        self._lock = threading.Lock()
        self._held: deque[tuple[float, np.ndarray]] = deque()  # (arrival, monotonic s; the frame)

    def set_truth(self, truth: m.Truth) -> None:
        with self._lock:
            self._truth = truth

    def _render(self) -> tuple[m.Truth, np.ndarray]:
        if self._newest_truth is not None and (newest := self._newest_truth()) is not None:
            self.set_truth(newest)
        with self._lock:
            truth = self._truth
        if truth is None:
            raise SourceError("no sim/truth yet: is the simulator running?")
        image, _ = self.renderer.render(truth.x, truth.y, truth.theta, turn_rate=truth.w)
        return truth, image

    def read(self) -> tuple[int, np.ndarray]:
        if self.delivery is None:
            self.pace.wait()
            truth, image = self._render()
            return truth.stamp, image  # the frame shows the world at the truth's time
        while True:
            now = time.monotonic()
            if self._held and self._held[0][0] <= now:
                return time.time_ns(), self._held.popleft()[1]  # stamped on arrival
            if self._held and self._held[0][0] < self.pace.next + self.pace.period:
                time.sleep(self._held[0][0] - now)  # the next frame arrives before the next exposure
                continue
            self.pace.wait()
            truth, image = self._render()
            # exposed when the pose was true: on the monotonic clock, the truth's age ago
            exposed = time.monotonic() - max(0.0, (time.time_ns() - truth.stamp) * 1e-9)
            arrival = self.delivery.arrival(exposed)
            if arrival is not None:
                self._held.append((arrival, image))

    def close(self) -> None:
        pass


class Retimed:
    """A source whose frames are stamped ``latency_ns`` earlier: when they were exposed, not when they
    arrived (the calibration's ``capture_latency_s``)."""

    def __init__(self, source: Source, latency_ns: int) -> None:
        self.source, self.latency_ns = source, latency_ns

    def read(self) -> tuple[int, np.ndarray]:
        stamp, image = self.source.read()
        return stamp - self.latency_ns, image

    def close(self) -> None:
        self.source.close()


def open_camera(config: RobotConfig, latency_s: float = 0.0,
                truth: Callable[[], m.Truth | None] | None = None) -> Source:
    """The source named by ``camera.source``, its stamps ``latency_s`` earlier; `SourceError` if it
    cannot be opened now. ``truth``: the simulated camera's newest true pose (`SimSource`)."""
    cam = config.camera
    source = open_source(cam.source, cam.width, cam.height, cam.fps, setting="camera.source",
                         sim=lambda: SimSource(config, truth))
    return Retimed(source, round(latency_s * 1e9)) if latency_s else source
