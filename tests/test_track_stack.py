"""A track world through real processes: the camera service renders the road in its frames, and a
bad layout file stops the simulator and the camera service with one line naming the file and field."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import cv2
import numpy as np
from conftest import Robot, wait_for

from icefloe.errors import EXIT_CONFIG
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.sim.camera import CameraRenderer
from icefloe.sim.floor import PAINT, edge_line_offset
from icefloe.vision.geometry import Intrinsics, Mount
from icefloe.worldmap import load_world

START = (-0.6, -0.6, 0.0)


async def test_the_camera_service_sends_the_road(make_robot) -> None:
    """The snapshot (the full frame, JPEG) at the start line shows the edge lines where the floor
    plane puts them (JPEG blurs them: within 3 px) and asphalt between them, in colour.
    Measured: 1.1 s (the router, the camera service starting, one frame); bounds of 30 s."""
    robot: Robot = make_robot('[sim]\nworld = "track"\n')
    cfg = robot.config
    renderer = CameraRenderer(load_world("track"), Intrinsics.from_config(cfg.camera), Mount.from_config(cfg.camera))
    _, lens, world_from_camera = renderer._camera(*START)
    track = renderer.world.track
    assert track is not None
    camera = robot.start("camera")
    async with robot.node("tester") as node:
        truth = node.publisher(keys.TRUTH)
        images = node.subscribe(keys.IMAGE, latest=False)

        async def drive_truth() -> None:  # we play the simulator: the robot stands on the start line
            while True:
                truth.put(m.Truth(stamp=time.time_ns(), x=START[0], y=START[1], theta=START[2]))
                await asyncio.sleep(0.05)

        task = asyncio.create_task(drive_truth())
        try:
            await asyncio.wait_for(images.__anext__(), 30)  # frames flow
            snap = await node.query(keys.SNAPSHOT, timeout=5.0)
        finally:
            task.cancel()
    frame = cv2.imdecode(np.frombuffer(snap.data, np.uint8), cv2.IMREAD_COLOR)
    for side in (-1, 1):
        point = np.array([[START[0] + 0.3, START[1] + side * edge_line_offset(track), 0.0]])
        u, v = renderer._frame_pixels((point - lens) @ world_from_camera)[0]
        row = frame[round(v)].astype(int)
        near = np.arange(round(u) - 3, round(u) + 4)
        assert (row[near] > np.array(PAINT) - 60).all(axis=1).any(), (side, u, row[near])
    middle = renderer._frame_pixels((np.array([[START[0] + 0.5, START[1] + 0.07, 0.0]]) - lens) @ world_from_camera)[0]
    assert frame[round(middle[1]), round(middle[0])].max() < 100
    pavement = frame[-1, -1].astype(int)  # bottom right: the concrete beside the road
    assert pavement.min() > 120
    assert camera.stop() == 0


async def test_a_bad_layout_starts_nothing_and_says_where(make_robot, tmp_path: Path) -> None:
    """The simulator and the camera service each exit at once with ``EXIT_CONFIG`` (not restarted:
    starting again cannot help) and one line. Measured: 0.6 s for both; bounds of 30 s each."""
    layout = tmp_path / "bent.toml"
    layout.write_text('tile_size = 0.6\nroad_width = 0.3\n[[tile]]\nkind = "straight"\ncol = 0\nrow = 0\n'
                      'rotation = 45\n')
    (tmp_path / "w.toml").write_text('track = "bent.toml"\n')
    robot: Robot = make_robot(f'[sim]\nworld = "{tmp_path / "w.toml"}"\n')
    for service in ("sim", "camera"):
        proc = robot.start(service)
        await wait_for(lambda proc=proc: not proc.alive(), timeout=30)
        assert proc.popen.returncode == EXIT_CONFIG, proc.output
        lines = [line for line in proc.output.splitlines() if line.strip()]
        assert len(lines) == 1 and f"{layout}: tile[0].rotation" in lines[0] and "Traceback" not in proc.output, \
            proc.output
