"""A made-up robot that publishes every message viz shows, at the real stack's rates.

    python -m icefloe.services.viz.demo --config sim            # then, elsewhere: python -m icefloe.services.viz

It drives a 1 m circle around the origin of the world file's lab. It is not a
simulator (``icefloe.sim`` is): nothing here reacts to commands. It exists so
viz can be tried, tested and benchmarked without the rest of the stack, over a
real Zenoh session with the real message types.
"""

from __future__ import annotations

import asyncio
import math
import random
import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from icefloe.angles import wrap_angle
from icefloe.config import RobotConfig
from icefloe.runtime import Node, run
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.schemas.keys import Topic
from icefloe.worldmap import Marker, load_world

RADIUS = 1.0
"""m: the circle the robot drives around the origin."""
SPEED = 0.2
"""m/s."""
FOV = math.radians(60)
"""Horizontal field of view of the made-up camera, rad."""

RATES_HZ = {  # the real stack's default rates
    keys.WHEELS: 100.0, keys.ODOM_POSE: 50.0, keys.TRUTH: 50.0, keys.LOC_POSE: 10.0,
    keys.LANDMARKS: 10.0, keys.IMAGE: 2.0, keys.HW_BATTERY: 10.0, keys.BATTERY: 1.0,
    keys.LOOP: 1.0, keys.OLED_FRAME: 5.0, keys.LOG: 0.5, keys.EXTLOC_POSE: 15.0,
}  # fmt: skip


@dataclass
class DemoRobot:
    """Every message of a robot on a circle, as a function of the time since it started."""

    config: RobotConfig
    markers: tuple[Marker, ...]
    seed: int = 1

    def __post_init__(self) -> None:
        self.rng = random.Random(self.seed)

    def truth(self, t: float) -> tuple[float, float, float]:
        angle = SPEED * t / RADIUS - math.pi / 2  # start at (0, -1) heading +x, driving anticlockwise
        theta = wrap_angle(angle + math.pi / 2)
        return RADIUS * math.cos(angle), RADIUS * math.sin(angle), theta

    def seen(self, t: float) -> list[m.Landmark]:
        """Markers in front of the camera, with range, bearing and pixel corners of a pinhole camera."""
        x, y, theta = self.truth(t)
        cam = self.config.camera
        f, cx, cy = cam.focal_px, (cam.width - 1) / 2, (cam.height - 1) / 2
        seen = []
        for mk in self.markers:
            r = math.hypot(mk.x - x, mk.y - y)
            bearing = math.remainder(math.atan2(mk.y - y, mk.x - x) - theta, math.tau)
            if abs(bearing) > FOV / 2 or r > 3.5:
                continue
            u, half = cx - f * math.tan(bearing), f * mk.size / 2 / r
            corners = [u - half, cy - half, u + half, cy - half, u + half, cy + half, u - half, cy + half]
            seen.append(m.Landmark(id=mk.id, range=r, bearing=bearing, corners=corners))
        return seen

    def message(self, topic: Topic, t: float, stamp: int) -> m.Message:
        x, y, theta = self.truth(t)
        w = SPEED / RADIUS
        half_track = self.config.geometry.track / 2
        left, right = SPEED - w * half_track, SPEED + w * half_track
        noise = self.rng.gauss
        if topic is keys.WHEELS:
            ticks_per_m = self.config.geometry.ticks_per_rev / (math.pi * self.config.geometry.wheel_diameter)
            return m.Wheels(stamp=stamp, ticks_left=int(left * t * ticks_per_m),
                            ticks_right=int(right * t * ticks_per_m), speed_left=left + noise(0, 0.01),
                            speed_right=right + noise(0, 0.01), target_left=left, target_right=right)
        if topic is keys.ODOM_POSE:  # odometry drifts: a slowly growing heading error
            return m.Pose(stamp=stamp, x=x + 0.01 * t * math.cos(theta), y=y, theta=theta, v=SPEED, w=w)
        if topic is keys.TRUTH:
            return m.Truth(stamp=stamp, x=x, y=y, theta=theta)
        if topic is keys.LOC_POSE:
            sx, sy = 0.02 + 0.01 * math.sin(t), 0.01
            return m.PoseEstimate(stamp=stamp, x=x + noise(0, 0.01), y=y + noise(0, 0.01), theta=theta,
                                  covariance=[sx * sx, 0.3 * sx * sy, 0, 0.3 * sx * sy, sy * sy, 0, 0, 0, 0.01])
        if topic is keys.EXTLOC_POSE:  # the lab's overhead camera: within a millimetre or so
            return m.ExternalPose(stamp=stamp, x=x + noise(0, 0.001), y=y + noise(0, 0.001), theta=theta,
                                  covariance=[1e-6, 0, 0, 0, 1e-6, 0, 0, 0, 1e-4], side_px=27.0)
        if topic is keys.LANDMARKS:
            return m.Landmarks(stamp=stamp, landmarks=self.seen(t))
        if topic is keys.IMAGE:
            return self.image(t, stamp)
        if topic is keys.HW_BATTERY:
            return m.BatteryReading(stamp=stamp, voltage=8.1 - 0.002 * t + noise(0, 0.02),
                                    current=0.6 + noise(0, 0.03))
        if topic is keys.BATTERY:
            return m.Battery(stamp=stamp, voltage=8.1 - 0.002 * t, current=0.6, state="ok")
        if topic is keys.LOOP:
            return m.LoopStats(stamp=stamp, rate=1000.0, period_mean=1e-3, period_max=1.2e-3,
                               latency_p50=20e-6, latency_p99=60e-6 + 20e-6 * math.sin(t),
                               latency_p999=120e-6, latency_max=300e-6, overruns=int(t // 10),
                               cycles=int(t * 1000), board="demo")
        if topic is keys.OLED_FRAME:
            return self.oled(x, y)
        if topic is keys.LOG:
            return m.Log(stamp=stamp, level="info", service="demo", text=f"at x={x:+.2f} y={y:+.2f}")
        raise ValueError(f"the demo robot does not publish {topic.name}")

    def image(self, t: float, stamp: int) -> m.Image:
        """A grey picture with the markers in view drawn as black squares, as a JPEG."""
        cam = self.config.camera
        picture = np.full((cam.image_height, cam.image_width), 170, np.uint8)
        scale = cam.image_width / cam.width  # corners are in capture pixels; the image is smaller
        for lm in self.seen(t):
            quad = (np.array(lm.corners).reshape(4, 2) * scale).astype(np.int32)
            cv2.fillConvexPoly(picture, quad, 20)
        ok, jpeg = cv2.imencode(".jpg", picture, [cv2.IMWRITE_JPEG_QUALITY, cam.jpeg_quality])
        assert ok, "OpenCV could not encode a JPEG"
        return m.Image(stamp=stamp, width=cam.image_width, height=cam.image_height, data=jpeg.tobytes())

    def oled(self, x: float, y: float) -> m.OledFrame:
        """The 128x32 screen with the pose written on it, packed 1 bit per pixel, MSB first."""
        screen = np.zeros((32, 128), np.uint8)
        cv2.putText(screen, self.config.name, (2, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1)
        cv2.putText(screen, f"{x:+.2f} {y:+.2f}", (2, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1)
        return m.OledFrame(width=128, height=32, pixels=np.packbits(screen > 0).tobytes())


async def publish(node: Node, robot: DemoRobot, duration: float | None = None,
                  sent: Callable[[Topic, m.Message], None] | None = None,
                  rates: dict[Topic, float] | None = None) -> None:
    """Publish every topic at its rate under ``node``'s robot name; ``sent`` sees each message."""
    start = time.monotonic()

    async def loop(topic: Topic, rate: float) -> None:
        pub = node.publisher(topic)
        next_at = time.monotonic()
        while duration is None or time.monotonic() - start < duration:
            msg = robot.message(topic, time.monotonic() - start, time.time_ns())
            pub.put(msg)
            if sent is not None:
                sent(topic, msg)
            next_at += 1.0 / rate
            await asyncio.sleep(max(0.0, next_at - time.monotonic()))

    async with asyncio.TaskGroup() as tasks:
        for topic, rate in (rates or RATES_HZ).items():
            tasks.create_task(loop(topic, rate))


async def main(config: RobotConfig) -> None:
    async with Node("demo", config) as node:
        node.log.info("a made-up robot %r drives a circle; `icefloe viz --robot %s` shows it; Ctrl-C stops",
                      config.name, config.name)
        await publish(node, DemoRobot(config, load_world(config.localizer.world).markers))


if __name__ == "__main__":
    run(main, description="a made-up robot on a circle, for trying viz")
