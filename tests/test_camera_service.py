"""The camera service as a real process: simulated frames, bad frames, a camera that disappears."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import Robot, wait_for

from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.sim.camera import CameraRenderer
from icefloe.vision.geometry import Intrinsics, Mount
from icefloe.worldmap import load_world


# 320x240: the nominal lens and the ideal profile, whose lens is the camera's: the shipped calibration and
# the realistic profile's lens are in 640x480 pixels (a calibration holds at its own resolution only)
@pytest.mark.parametrize("camera", ["", "[camera]\nwidth = 320\nheight = 240\nfocal_px = 250.0\nimage_width = 160\n"
                                        'image_height = 120\ncalibration = ""\n[sim]\nprofile = "ideal"\n'],
                         ids=["640x480", "320x240"])
async def test_simulated_camera_publishes_landmarks_images_and_snapshots(make_robot, camera: str) -> None:
    """At the default 640x480 and at a robot's smaller frame (the same lens: the focal length
    halved with the width), the simulated camera renders the configured size, and the same
    markers are found in it."""
    robot: Robot = make_robot(camera)
    cfg = robot.config
    renderer = CameraRenderer(load_world(cfg.sim.world), Intrinsics.from_config(cfg.camera),
                              Mount.from_config(cfg.camera), cfg.camera.dictionary)
    expected = {v.id for v in renderer.render(0.0, 0.0, 0.0)[1]}
    assert expected
    camera = robot.start("camera")
    async with robot.node("tester") as node:
        marks = node.subscribe(keys.LANDMARKS, latest=False, maxsize=1000)
        images = node.subscribe(keys.IMAGE, latest=False)
        truth = node.publisher(keys.TRUTH)

        async def drive_truth() -> None:  # we play the simulator: the robot stands at the origin
            while True:
                truth.put(m.Truth(stamp=time.time_ns(), x=0.0, y=0.0, theta=0.0))
                await asyncio.sleep(0.05)

        task = asyncio.create_task(drive_truth())
        try:
            seen: set[int] = set()
            deadline = time.monotonic() + 20
            while not expected <= seen and time.monotonic() < deadline:
                frame = await asyncio.wait_for(marks.__anext__(), 20)
                seen |= {lm.id for lm in frame.landmarks}
            assert expected <= seen, (expected, seen)
            image = await asyncio.wait_for(images.__anext__(), 10)
            small = cv2.imdecode(np.frombuffer(image.data, np.uint8), cv2.IMREAD_COLOR)
            assert small.shape == (cfg.camera.image_height, cfg.camera.image_width, 3)
            snap = await node.query(keys.SNAPSHOT, timeout=5.0)
            full = cv2.imdecode(np.frombuffer(snap.data, np.uint8), cv2.IMREAD_COLOR)
            assert full.shape == (cfg.camera.height, cfg.camera.width, 3) == (snap.height, snap.width, 3)
        finally:
            task.cancel()
    assert camera.stop() == 0


async def test_bad_frames_and_a_camera_that_disappears_are_logged_and_survived(make_robot, tmp_path: Path) -> None:
    folder = tmp_path / "frames"
    folder.mkdir()
    (folder / "0-corrupt.jpg").write_bytes(b"\xff\xd8\xff\xe0 this is not a JPEG")
    (folder / "1-empty.jpg").write_bytes(b"")
    cv2.imwrite(str(folder / "2-small.png"), np.zeros((240, 320, 3), np.uint8))
    good = np.full((480, 640, 3), 200, np.uint8)
    cv2.imwrite(str(folder / "3-good.png"), good)
    robot = make_robot(f'[camera]\nsource = "{folder}"\nfps = 20.0\n')
    camera = robot.start("camera")
    async with robot.node("tester") as node:
        logs = node.subscribe(keys.LOG, latest=False, maxsize=1000)
        marks = node.subscribe(keys.LANDMARKS, latest=False, maxsize=1000)
        texts: list[str] = []

        async def collect() -> None:
            async for entry in logs:
                texts.append(entry.text)

        task = asyncio.create_task(collect())
        try:
            await wait_for(lambda: any("not a readable image" in t for t in texts), timeout=20)
            await wait_for(lambda: any("expected 480x640" in t for t in texts), timeout=20)
            await asyncio.wait_for(marks.__anext__(), 10)  # the good frame still goes through
            for f in folder.iterdir():  # the camera disappears
                f.unlink()
            folder.rmdir()
            await wait_for(lambda: any("folder missing or empty" in t for t in texts), timeout=20)
            assert camera.alive()
            folder.mkdir()  # ... and comes back: frames flow again
            cv2.imwrite(str(folder / "good.png"), good)
            while marks.pending():
                await marks.__anext__()
            await wait_for(lambda: marks.pending() > 0, timeout=20)
        finally:
            task.cancel()
    assert camera.stop() == 0


async def test_detection_runs_at_its_configured_rate_not_the_capture_rate(make_robot, tmp_path: Path) -> None:
    """``camera.detection_rate_hz = 5`` with frames captured at 20 a second: ``camera/landmarks``
    comes about 5 times a second (the frames between are passed over, not queued), and the
    images still come. Measured from the frames' stamps: 4.9-5.0 Hz in three runs (2026-12-07, load 10-12);
    20.7 Hz without the setting."""
    folder = tmp_path / "frames"
    folder.mkdir()
    cv2.imwrite(str(folder / "good.png"), np.full((480, 640, 3), 200, np.uint8))
    # one still picture: rest_detection_rate_hz at fps, or the camera would rest (test_camera_rest_service.py)
    robot = make_robot(f'[camera]\nsource = "{folder}"\nfps = 20.0\ndetection_rate_hz = 5.0\n'
                       'rest_detection_rate_hz = 20.0\n')
    camera = robot.start("camera")
    async with robot.node("tester") as node:
        marks = node.subscribe(keys.LANDMARKS, latest=False, maxsize=1000)
        images = node.subscribe(keys.IMAGE, latest=False)
        await asyncio.wait_for(marks.__anext__(), 30)  # the first: start-up is behind us
        stamps = [(await asyncio.wait_for(marks.__anext__(), 10)).stamp for _ in range(11)]
        rate = 10 / ((stamps[-1] - stamps[0]) * 1e-9)
        assert 2.5 <= rate <= 6.0, f"camera/landmarks at {rate:.1f} Hz, configured 5 (frames at 20)"
        await asyncio.wait_for(images.__anext__(), 10)
    assert camera.stop() == 0
