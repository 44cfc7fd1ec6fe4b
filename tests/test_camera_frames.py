"""`Frames`: the latest frame encoded once, however many threads ask at once."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
import pytest

from icefloe.config import Camera
from icefloe.services.camera import frames as frames_mod
from icefloe.services.camera.frames import Frames


@pytest.mark.parametrize("full", [False, True])
def test_a_burst_of_askers_gets_one_jpeg_per_frame(monkeypatch: pytest.MonkeyPatch, full: bool) -> None:
    camera = Camera()
    encoded: list[int] = []
    real_jpeg = frames_mod.jpeg

    def slow_jpeg(image: np.ndarray, quality: int) -> bytes:
        encoded.append(quality)
        threading.Event().wait(0.05)  # long enough for every asker to arrive while it encodes
        return real_jpeg(image, quality)

    monkeypatch.setattr(frames_mod, "jpeg", slow_jpeg)
    encoder = Frames(camera, full=full, quality=90)
    rng = np.random.default_rng(1)
    frame = (123, rng.integers(0, 255, (camera.height, camera.width, 3), dtype=np.uint8))
    with ThreadPoolExecutor(16) as pool:
        answers = list(pool.map(lambda _: encoder.of(frame), range(32)))
    assert encoded == [90] and all(a is answers[0] for a in answers)
    image = cv2.imdecode(np.frombuffer(answers[0].data, np.uint8), cv2.IMREAD_COLOR)
    size = (camera.width, camera.height) if full else (camera.image_width, camera.image_height)
    assert (answers[0].width, answers[0].height) == size and image.shape == (size[1], size[0], 3)
    assert answers[0].stamp == 123
    # A new frame: one more JPEG.
    newer = (124, frame[1].copy())
    assert encoder.of(newer).stamp == 124 and encoder.of(newer) is encoder.of(newer) and len(encoded) == 2
