"""`icefloe snapshot` and `icefloe calibrate` end to end: the real simulator, hwbridge, odometry,
info and camera processes of ``deploy/robots/sim-calibration.toml``, whose simulated lens
(``[sim.lens]``) differs from what the camera service assumes, and the command line as a student
types it. What the calibration finds is compared with that lens.
"""

from __future__ import annotations

import asyncio
import subprocess
import sys

import cv2
import numpy as np
import pytest
from conftest import ROOT
from test_client_sim import started
from test_hwbridge_helpers import sim_state

from icefloe import config as config_mod
from icefloe.schemas import keys
from icefloe.vision.geometry import Intrinsics

pytestmark = pytest.mark.slow

BASE = ROOT / "deploy" / "robots" / "sim-calibration.toml"


async def icefloe(*args: str, stdin: str = "", timeout: float = 300) -> subprocess.CompletedProcess:
    return await asyncio.to_thread(subprocess.run, [sys.executable, "-m", "icefloe.cli", *args], cwd=ROOT,
                                   input=stdin, capture_output=True, text=True, timeout=timeout)


async def first_frame(robot, node) -> None:
    """Wait until the camera service has a frame (it needs the simulator's truth first)."""
    frames = node.subscribe(keys.LANDMARKS)
    await asyncio.wait_for(anext(frames), 60)
    frames.close()


@pytest.mark.timeout(400)  # a scan of the board: about 40 s alone, several times that on a loaded machine
async def test_snapshot_and_calibrate_find_the_simulated_lens(make_robot, tmp_path):
    robot = make_robot(base=BASE)
    for service in ("sim", "hwbridge", "odometry", "info", "camera"):
        robot.start(service)
    config = str(robot.config_path)
    async with robot.node() as node:
        await started(robot, node, "odometry", "info", "camera")
        await first_frame(robot, node)
        start = await sim_state(node)

        # snapshot: the camera's own JPEG, or converted by the suffix; a bad folder is one line.
        done = await icefloe("snapshot", str(tmp_path / "frame.jpg"), "--config", config)
        assert done.returncode == 0, done.stderr
        assert done.stdout.startswith(f"{tmp_path / 'frame.jpg'}: 640x480, ")
        frame = cv2.imread(str(tmp_path / "frame.jpg"))
        assert frame.shape == (480, 640, 3) and (tmp_path / "frame.jpg").read_bytes()[:2] == b"\xff\xd8"
        done = await icefloe("snapshot", str(tmp_path / "frame.png"), "--config", config)
        assert done.returncode == 0 and cv2.imread(str(tmp_path / "frame.png")).shape == (480, 640, 3)
        done = await icefloe("snapshot", str(tmp_path / "nowhere" / "f.jpg"), "--config", config)
        assert done.returncode == 2 and done.stderr.strip().endswith("f.jpg: no folder "
                                                                     f"{tmp_path / 'nowhere'} to save it in")

        # Interactive, as a student at the keyboard: Enter captures, the same view twice is refused,
        # u drops a view, q with too few views writes nothing.
        done = await icefloe("calibrate", "--config", config, stdin="\n\nu\nq\n")
        assert done.returncode == 2, done.stdout + done.stderr
        assert "view 1: board found (54 corners)" in done.stdout
        assert "the board is where it was in an earlier view" in done.stdout
        assert "dropped view 1" in done.stdout
        assert "0 views are too few" in done.stderr and "nothing written" in done.stderr

        # Hands-free: the robot scans the board by itself, then computes and writes.
        done = await icefloe("calibrate", "--config", config, "--auto", "10", "--drive",
                             "--save-views", str(tmp_path / "views"))
        print(done.stdout)
        assert done.returncode == 0, done.stdout + done.stderr
        assert len(list((tmp_path / "views").glob("view-*.jpg"))) == 10
        back = await sim_state(node)
        assert np.hypot(back.x - start.x, back.y - start.y) < 0.05, "it did not come back to its start"

    # The config now names the calibration; the camera service reads it from there.
    cfg = config_mod.load(robot.config_path)
    assert cfg.camera.calibration == str(robot.config_path.with_name(f"{robot.name}.camera.yaml"))
    found = Intrinsics.from_config(cfg.camera)
    k, d = found.camera_matrix, found.dist_coeffs
    lens = cfg.sim.lens
    print(f"found fx {k[0, 0]:.1f} (true {lens.fx}) fy {k[1, 1]:.1f} ({lens.fy}) cx {k[0, 2]:.1f} ({lens.cx}) "
          f"cy {k[1, 2]:.1f} ({lens.cy}) k1 {d[0]:.3f} ({lens.distortion[0]})")
    assert k[0, 0] == pytest.approx(lens.fx, rel=0.03) and k[1, 1] == pytest.approx(lens.fy, rel=0.03)
    assert k[0, 2] == pytest.approx(lens.cx, abs=6) and k[1, 2] == pytest.approx(lens.cy, abs=8)
    assert d[0] == pytest.approx(lens.distortion[0], abs=0.03)
    rms = float(done.stdout.split("RMS reprojection error ")[1].split(" px")[0])
    assert rms < 0.5
    camera = next(p for p in robot.procs if p.name == "camera")
    assert camera.stop() == 0
    restarted = robot.start("camera")  # a bad calibration file would stop it at start, saying why
    async with robot.node() as node:
        await first_frame(robot, node)
    assert restarted.alive(), restarted.output


async def test_snapshot_without_a_camera_says_so_in_one_line(robot, tmp_path):
    done = await icefloe("snapshot", str(tmp_path / "f.jpg"), "--config", str(robot.config_path), "--timeout", "1")
    assert done.returncode == 2 and not (tmp_path / "f.jpg").exists()
    assert done.stderr.count("\n") == 1 and f"icefloe/{robot.name}/camera/snapshot: nobody answers" in done.stderr
    assert "(after 1 s)" in done.stderr
