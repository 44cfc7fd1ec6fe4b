"""The simulated camera's light, auto exposure and sensor: what the realistic profile does to a frame.

The renderer (`sim.camera`) draws the world as the lens sees it; this module makes a camera's
picture of it (`icefloe.sim.realism.Picture` gives the numbers):

* **Light that varies over the arena** (`LightField`): a few ceiling lamps over the room; each marker,
  board and obstacle face is drawn as bright as the light where it hangs, relative to the light where
  the camera looks (auto exposure makes that part of the picture look normal).
* **Auto exposure** (`split_exposure`): the exposure a frame needs (``exposure_s`` where the light is
  average, longer where it is dimmer) is split into a shutter time and an analogue gain the way the
  Raspberry Pi camera's normal exposure mode does it: the shutter to 10 ms, then gain, then a longer
  shutter, and so on (`AE_STEPS`).
* **Motion blur**: the robot turning at w rad/s during a shutter of t s smears the frame sideways by
  fx · w · t pixels. (Driving straight moves the picture far less: 4 mm of travel shifts a marker 1 m
  away by under a pixel, so only the turn is drawn.)
* **Sensor noise** grows with the gain: in the dark the picture is noisier.
* **The lens's own softness** (``blur_px``), **flicker**, and **JPEG compression** (``jpeg_quality``).
"""

from __future__ import annotations

import itertools
import math

import cv2
import numpy as np

from icefloe.worldmap import WorldMap

from .realism import Picture

AE_STEPS = ((0.0001, 1.0), (0.010, 1.0), (0.010, 2.0), (0.030, 2.0), (0.030, 4.0), (0.060, 4.0),
            (0.060, 6.0), (0.0667, 6.0), (0.0667, 8.0))
"""(shutter s, analogue gain) corners auto exposure walks through as the light falls: the Raspberry Pi
camera's normal exposure mode (libcamera's rpi tuning: shutter 100, 10000, 30000, 60000, 66666 µs;
gain 1, 2, 4, 6, 8). Between two corners one of the two grows; beyond the last, the picture darkens."""
LAMPS = 4
"""Ceiling lamps over the room (`LightField`)."""
LAMP_SPREAD = 1.2
"""How far a lamp's light reaches, m (the standard deviation of its pool of light on the floor)."""
NOISE_BANK = 4
"""Noise images drawn once, one picked per frame (drawing 300 k normals a frame would cost more than the
rest of the render)."""


def split_exposure(total_s: float) -> tuple[float, float]:
    """(shutter s, gain) giving an exposure of ``total_s`` (shutter x gain) along `AE_STEPS`."""
    total_s = max(total_s, AE_STEPS[0][0])
    for (t0, g0), (t1, g1) in itertools.pairwise(AE_STEPS):
        if total_s <= t1 * g1:
            return (total_s / g0, g0) if t1 > t0 else (t0, total_s / t0)
    shutter, gain = AE_STEPS[-1]
    return shutter, gain  # as long and as loud as it goes: the picture is darker than wanted


class LightField:
    """How much light falls where, relative: 1 under the brightest lamp, ``1 - variation`` in the
    darkest place of the room (a few lamps placed by ``rng`` over the world's extent)."""

    def __init__(self, world: WorldMap, variation: float, rng: np.random.Generator) -> None:
        points = [(mk.x, mk.y) for mk in world.faces()] + [(b.x, b.y) for b in world.boards]
        for o in world.obstacles:
            cx, cy, *_ = o.rectangle()
            points.append((cx, cy))
        if world.track is not None:  # a track's lamps hang over its tiles
            ts = world.track.tile_size
            points += [(t.col * ts, t.row * ts) for t in world.track.tiles]
        pts = np.array(points or [(0.0, 0.0)], dtype=float).reshape(-1, 2)
        low, high = pts.min(axis=0) - 0.5, pts.max(axis=0) + 0.5
        self.variation = variation
        self._lamps = rng.uniform(low, high, (LAMPS, 2))
        self._power = rng.uniform(0.5, 1.0, LAMPS)
        # Scale so that the room, sampled on a grid, spans exactly [1 - variation, 1].
        gx, gy = np.meshgrid(np.linspace(low[0], high[0], 40), np.linspace(low[1], high[1], 40))
        raw = self._raw(np.stack([gx.ravel(), gy.ravel()], axis=1))
        self._low, self._span = float(raw.min()), float(raw.max() - raw.min()) or 1.0
        self.mean = float(self.at(np.stack([gx.ravel(), gy.ravel()], axis=1)).mean())
        """The light averaged over the room."""

    def _raw(self, xy: np.ndarray) -> np.ndarray:
        d2 = ((xy[:, None, :] - self._lamps[None, :, :]) ** 2).sum(axis=2)
        return (self._power * np.exp(-d2 / (2 * LAMP_SPREAD**2))).sum(axis=1)

    def at(self, xy: np.ndarray) -> np.ndarray:
        """The light at each floor point (n, 2) m: (n,) in [1 - variation, 1] (beyond the room, clipped)."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        if not self.variation:
            return np.ones(len(xy))
        rel = (self._raw(xy) - self._low) / self._span
        return 1.0 - self.variation * (1.0 - np.clip(rel, 0.0, 1.0))


def smear(image: np.ndarray, length_px: float) -> np.ndarray:
    """``image`` averaged along rows over ``length_px`` pixels, centred: the picture of a camera that
    turned by that much while its shutter was open (each tap weighs its pixel's overlap with the box)."""
    if length_px < 0.5:
        return image
    half = length_px / 2
    n = math.ceil(half - 0.5)
    k = np.arange(-n, n + 1, dtype=np.float32)
    kernel = np.clip(np.minimum(k + 0.5, half) - np.maximum(k - 0.5, -half), 0.0, None)
    kernel /= kernel.sum()
    return cv2.filter2D(image, -1, kernel.reshape(1, -1), borderType=cv2.BORDER_REPLICATE)


class Sensor:
    """From the drawn frame (grey; BGR with ``colour``, a track's world) to the camera's BGR picture:
    motion blur, the lens's softness, flicker, noise at the gain auto exposure chose, JPEG; draws from
    ``rng`` (seeded: repeatable)."""

    def __init__(self, picture: Picture, fx: float, width: int, height: int, rng: np.random.Generator,
                 *, colour: bool = False) -> None:
        self.picture, self.fx = picture, fx
        self._rng = rng
        self._colour = colour
        shape = (height, width, 3) if colour else (height, width)
        self._bank = [rng.standard_normal(shape, dtype=np.float32) for _ in range(NOISE_BANK)]
        self.shutter_s, self.gain = split_exposure(picture.exposure_s)
        """The last frame's shutter time (s) and analogue gain."""

    def expose(self, drawn: np.ndarray, turn_rate: float, light: float, mean_light: float) -> np.ndarray:
        """The picture of ``drawn`` (drawn as auto exposure renders the place the camera looks at, whose
        light is ``light``; the room's average is ``mean_light``) while turning at ``turn_rate`` rad/s."""
        p = self.picture
        self.shutter_s, self.gain = split_exposure(p.exposure_s * mean_light / max(light, 1e-3))
        image = smear(drawn, self.fx * abs(turn_rate) * self.shutter_s) if p.exposure_s else drawn
        if p.blur_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), p.blur_px)
        flicker = 1.0 + p.flicker * self._rng.uniform(-1.0, 1.0)
        noise = self._bank[self._rng.integers(len(self._bank))]
        sigma = p.noise * self.gain
        image = cv2.addWeighted(image.astype(np.float32), flicker, noise, sigma, 0.0, dtype=cv2.CV_8U)
        if p.jpeg_quality:
            ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, p.jpeg_quality])
            if ok:
                image = cv2.imdecode(data, cv2.IMREAD_COLOR if self._colour else cv2.IMREAD_GRAYSCALE)
        return image if self._colour else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)


class Delivery:
    """The camera's pipeline between the exposure and the service: each frame arrives ``latency_s``
    (± ``latency_jitter_s``, never before the frame ahead of it) after its exposure, and
    ``drop_rate`` of them never do; draws from ``rng`` (seeded). Times are in seconds of one clock."""

    def __init__(self, picture: Picture, rng: np.random.Generator) -> None:
        self.picture = picture
        self._rng = rng
        self._last = -math.inf
        self.dropped = 0
        """Frames lost so far."""

    def arrival(self, exposed_at: float) -> float | None:
        """When the frame exposed at ``exposed_at`` arrives; None if the pipeline loses it."""
        p = self.picture
        delay = p.latency_s + (p.latency_jitter_s * self._rng.standard_normal() if p.latency_jitter_s else 0.0)
        lost = p.drop_rate > 0 and self._rng.random() < p.drop_rate
        if lost:
            self.dropped += 1
            return None
        self._last = max(self._last, exposed_at + max(0.0, delay))  # a pipeline hands frames over in order
        return self._last
