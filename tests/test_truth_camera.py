"""The truth-played camera (icefloe/testing.py: `TruthCamera`, `play_camera`) that the localizer's,
SLAM's and the map maker's tests use in place of the camera service, and the landmark helpers SLAM
and the map maker share (icefloe/estimation/landmarks.py)."""

from __future__ import annotations

import asyncio
import logging
import math
import random

import numpy as np

from icefloe.config import RobotConfig
from icefloe.estimation.landmarks import MAX_RANGE, landmark_map, plausible
from icefloe.logs import LimitedLog
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.testing import UNKNOWN_ID, TruthCamera, eventually, local_bus, play_camera
from icefloe.worldmap import load_world

CONFIG = RobotConfig()


def test_a_noiseless_camera_sees_the_markers_in_view_exactly_and_counts_them() -> None:
    camera = TruthCamera(CONFIG, random.Random(1), sigma_range=0.0, sigma_range_rel=0.0, sigma_bearing=0.0)
    frame = camera.frame((0.0, 0.0, 0.0), 42)
    half_fov = math.atan2(CONFIG.camera.width / 2, CONFIG.camera.focal_px)
    expected = {}
    for mk in load_world(CONFIG.localizer.world).markers:
        rng, bearing = math.hypot(mk.x, mk.y), math.atan2(mk.y, mk.x)
        if abs(bearing) <= half_fov and 0.2 < rng < 3.0:
            expected[mk.id] = (rng, bearing)
    assert frame.stamp == 42 and expected
    assert {lm.id: (lm.range, lm.bearing) for lm in frame.landmarks} == expected
    assert camera.sightings == len(expected) and camera.injected_outliers == 0


def test_made_up_errors_are_counted_and_a_seed_repeats_them() -> None:
    def frames(seed: int) -> tuple[list[m.Landmarks], TruthCamera]:
        camera = TruthCamera(CONFIG, random.Random(seed), outlier_rate=1.0, unknown_rate=1.0)
        return [camera.frame((0.0, 0.0, 0.1 * k), k) for k in range(5)], camera

    first, camera = frames(3)
    assert camera.injected_outliers == camera.sightings - 5  # every sighting of the map, not the 5 unknown
    assert all(frame.landmarks[-1].id == UNKNOWN_ID for frame in first)
    assert frames(3)[0] == first and frames(4)[0] != first


async def test_play_camera_puts_every_third_truths_sightings_on_camera_landmarks() -> None:
    async with local_bus("truthcam") as config, Node("player", config) as player, Node("tester", config) as tester:
        seen: list[tuple[int, bool]] = []
        landmarks = tester.subscribe(keys.LANDMARKS, latest=False)
        camera = TruthCamera(config, random.Random(2))
        task = asyncio.create_task(play_camera(player, camera, on_truth=lambda t, f: seen.append((t.stamp,
                                                                                                   f is not None))))
        truth = tester.publisher(keys.TRUTH)
        stamp = 0

        async def put_truths() -> bool:  # (again until the subscription has reached the player)
            nonlocal stamp
            stamp += 1
            truth.put(m.Truth(stamp=stamp, x=0.0, y=0.0, theta=0.0))
            return len(seen) >= 6

        await eventually(put_truths, timeout=20)
        frames = [await asyncio.wait_for(anext(landmarks), 10) for _ in range(2)]
        task.cancel()
    assert [made for _, made in seen] == [n % 3 == 0 for n in range(1, len(seen) + 1)]  # the 3rd, the 6th, ...
    played = [stamp for stamp, made in seen if made]
    assert [f.stamp for f in frames] == played[:2] and all(f.landmarks for f in frames)


def test_implausible_sightings_are_dropped_with_one_line(caplog) -> None:
    good = m.Landmark(id=1, range=1.0, bearing=0.5)
    frame = m.Landmarks(stamp=1, landmarks=[good, m.Landmark(id=2, range=MAX_RANGE + 1, bearing=0.0),
                                            m.Landmark(id=3, range=0.0, bearing=0.0)])
    caplog.set_level(logging.WARNING)
    assert plausible(frame, LimitedLog(logging.getLogger("icefloe.test-landmarks"))) == [good]
    assert caplog.text.count("is not a sighting") == 1 and "landmark 2" in caplog.text


def test_a_filters_map_is_a_landmark_map_message_in_id_order() -> None:
    class Filter:
        def __init__(self) -> None:
            self.landmarks = {7: (1.0, 2.0), 3: (-1.0, 0.5)}

        def covariance(self, landmark_id: int) -> np.ndarray:
            return np.eye(2) * landmark_id

    lm = landmark_map(Filter(), 99)
    assert lm.stamp == 99 and [p.id for p in lm.landmarks] == [3, 7]
    assert lm.landmarks[1].x == 1.0 and lm.landmarks[1].covariance == [7.0, 0.0, 0.0, 7.0]
