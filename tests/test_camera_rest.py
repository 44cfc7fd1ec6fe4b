"""The camera at rest (services/camera/rest.py), on the simulator's own frames with an injected clock
(pure: no bus): a still picture rests, a flickering one too, a turn or a marker appearing ends the rest."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import robot_config

from icefloe import config as config_mod
from icefloe.services.camera.rest import DetectionRest, change, thumbnail
from icefloe.sim.camera import CameraRenderer

FPS = 15.0
POSE = (0.3, -0.2, 0.6)
"""A pose of the lab with markers in view."""


def renderer(tmp_path: Path, profile: str) -> tuple[CameraRenderer, config_mod.RobotConfig]:
    cfg = config_mod.load(str(robot_config(tmp_path, f"rest{profile}", f'[sim]\nprofile = "{profile}"\n')))
    return CameraRenderer.of_robot(cfg, seed=5), cfg


def searched(rest: DetectionRest, frames: list[np.ndarray], start: float = 0.0) -> list[float]:
    """The times of the frames searched, the frames due at `FPS` from ``start``."""
    times = [start + i / FPS for i in range(len(frames))]
    return [t for t, image in zip(times, frames, strict=True) if rest.search(thumbnail(image), t)]


def rest_of(cfg: config_mod.RobotConfig) -> DetectionRest:
    cam = cfg.camera
    return DetectionRest(cam.still_threshold, cam.rest_after_s, 1.0 / cam.rest_detection_rate_hz)


@pytest.mark.parametrize("profile", ["ideal", "realistic"])
def test_a_still_flickering_picture_rests_after_rest_after_s_and_is_searched_at_the_rest_rate(
        tmp_path: Path, profile: str) -> None:
    """The ideal profile's flicker is ±15 % a frame, the realistic one's noise, exposure and JPEG:
    46 frames (3 s) of a standing robot are searched for 1 s, then once a second."""
    render, cfg = renderer(tmp_path, profile)
    frames = [render.render(*POSE)[0] for _ in range(46)]
    rest = rest_of(cfg)
    times = searched(rest, frames)
    assert rest.resting and rest.rests == 1 and rest.wakes == 0
    full = [t for t in times if t < cfg.camera.rest_after_s]
    assert len(full) == 15  # every frame of the first second
    resting = [t for t in times if t >= cfg.camera.rest_after_s]
    assert 2 <= len(resting) <= 3, times  # 1 Hz over the other 2 s
    assert all(b - a >= 1.0 - 1e-6 for a, b in itertools.pairwise(resting))


def test_a_turn_ends_the_rest_at_once_and_every_frame_is_searched_while_turning(tmp_path: Path) -> None:
    render, cfg = renderer(tmp_path, "realistic")
    x, y, theta = POSE
    still = [render.render(x, y, theta)[0] for _ in range(30)]
    turning = [render.render(x, y, theta + 0.5 * (i + 1) / FPS, turn_rate=0.5)[0] for i in range(15)]
    rest = rest_of(cfg)
    searched(rest, still)
    assert rest.resting
    times = searched(rest, turning, start=30 / FPS)
    assert not rest.resting and rest.wakes == 1
    assert times[0] == pytest.approx(30 / FPS)  # the first frame of the turn
    assert len(times) >= 12, "the turning robot's frames were passed over"


def test_a_marker_appearing_in_a_corner_ends_the_rest(tmp_path: Path) -> None:
    """A marker 40 px wide (a 15 cm marker 1.9 m away) put into a still picture's corner, as by hand."""
    render, cfg = renderer(tmp_path, "realistic")
    still = [render.render(*POSE)[0] for _ in range(30)]
    rest = rest_of(cfg)
    searched(rest, still)
    assert rest.resting
    marker = cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), 7, 40)
    shown = render.render(*POSE)[0].copy()
    shown[400:440, 560:600] = marker[..., None]
    assert rest.search(thumbnail(shown), 31 / FPS), f"change {rest.last_change:.3f}"
    assert not rest.resting and rest.wakes == 1


def test_slow_change_adds_up_against_the_spells_first_frame() -> None:
    """Each frame only a little brighter in one corner than the one before: compared with the spell's
    first frame, the change adds up and ends the spell; frame to frame it never would."""
    rest = DetectionRest(threshold=0.25, rest_after_s=1.0, rest_period_s=1.0)
    image = np.full((480, 640), 100, np.uint8)
    image[:, :320] = 60
    frames = []
    for i in range(32):
        frame = image.copy()
        frame[:40, :40] = 100 + i  # +0.0125 of the mean a frame: 0.25 after 20 frames
        frames.append(frame)
    assert max(change(thumbnail(a), thumbnail(b)) for a, b in itertools.pairwise(frames)) < 0.02
    searched(rest, frames)
    assert rest.rests == 1 and rest.wakes == 1  # rested after 1 s, woken when the corner had brightened 0.25


def test_a_black_picture_is_still_and_does_not_divide_by_zero() -> None:
    rest = DetectionRest(threshold=0.25, rest_after_s=0.5, rest_period_s=1.0)
    black = np.zeros((480, 640, 3), np.uint8)
    times = searched(rest, [black] * 30)
    assert rest.resting and math.isfinite(rest.last_change) and len(times) == 8 + 1  # 0.5 s of frames, then 1 Hz


def test_the_rest_rate_above_fps_is_refused_naming_the_key(tmp_path: Path) -> None:
    with pytest.raises(config_mod.ConfigError, match="rest_detection_rate_hz"):
        config_mod.load(str(robot_config(tmp_path, "fast", "[camera]\nfps = 10.0\nrest_detection_rate_hz = 12.0\n")))
