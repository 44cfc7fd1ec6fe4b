"""The localizer at rest on rendered frames, with the marker detector's corner inset undone (the calibration
`icefloe calibrate` measures with a ChArUco board of the robot's dictionary, docs/camera.md) and without:
sim + hwbridge + odometry + camera + localizer as real processes, the ideal profile, against `sim/truth`;
one sim, hwbridge and odometry for both runs, the camera and the localizer started anew for each.

    .venv/bin/pytest -s tests/test_localizer_at_rest.py     # prints the figures
"""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest
from conftest import wait_for
from test_localizer_sim import check_exits, collect

from icefloe import config as config_mod
from icefloe.schemas import keys
from icefloe.sim.camera_calibration import calibrate_camera

pytestmark = pytest.mark.slow

POSE = (1.0, 0.75, -0.785)
"""Where the robot stands: markers 1 and 0 in view, 1.25 and 2.19 m away, seen at 37 and 63 degrees from
square on (the lab has no place that shows three markers between 0.6 and 2.2 m)."""
HOLD_S = 2.0
"""How long the pose is watched once both markers have been seen, s (4 s gave the same medians to 0.01 cm)."""


async def watch(robot) -> tuple[float, float]:
    """(position error m, heading error rad) of loc/pose against the truth, the median over `HOLD_S`: the
    camera and the localizer started on the running sim, hwbridge and odometry, and stopped after."""
    procs = [robot.start(s) for s in ("camera", "localizer")]
    truth, loc, frames = [], [], []
    async with robot.node("tester") as node:
        tasks = [asyncio.create_task(collect(node.subscribe(topic, latest=False, maxsize=1024), into))
                 for topic, into in ((keys.TRUTH, truth), (keys.LOC_POSE, loc), (keys.LANDMARKS, frames))]
        await wait_for(lambda: truth and len({lm.id for f in frames for lm in f.landmarks}) >= 2, timeout=60)
        start = len(loc)
        await asyncio.sleep(HOLD_S)
        for task in tasks:
            task.cancel()
    for proc in procs:
        assert proc.alive(), proc.output
        assert proc.stop() == 0, proc.output
    t = truth[-1]
    held = loc[start:]
    assert len(held) > 10, "the localizer published too little"
    position = float(np.median([math.hypot(p.x - t.x, p.y - t.y) for p in held]))
    heading = float(np.median([abs(math.remainder(p.theta - t.theta, math.tau)) for p in held]))
    return position, heading


@pytest.mark.timeout(300)
async def test_the_localizer_at_rest_with_the_inset_undone(make_robot, tmp_path) -> None:
    """Measured (2026-12-07, load 2-3, 8.8-9.8 s wall for both runs, four runs): as detected 0.93-0.94 cm
    0.07 deg, inset undone 0.61 cm 0.18 deg in every run (the figure is geometry, not timing: a busy
    machine only changes how many frames the median takes), so the bounds (1.0 cm, 0.5 deg) are 1.6 and
    2.8 times it: the issue's goal, within 1 cm.
    Before the simulator drew markers anti-aliased (sim/camera.py, `SUPERSAMPLE`): 1.87 cm 0.48 deg as
    detected, 1.66-1.67 cm 0.59 deg undone. A plain warp put the black square's edges where pixel centres
    fell, so the detector's corners were off per marker (0.45 px inside on marker 1, 0.05 px outside on
    marker 0), which the inset measured on the anti-aliased calibration board could not undo. What is left
    (rendered frames at this pose, 30 frames, inset undone): marker 1 +0.12 cm, marker 0 -1.50 cm: seen
    63 degrees from square on, its cells are 2.9 px wide across and 6.2 px high, and the detector puts
    its top and bottom edges about 0.1 px inside the square, not the 0.23 px the calibration's inset
    says for a marker of its mean side (docs/camera.md)."""
    x, y, theta = POSE
    # ideal, the nominal lens: the subject is the inset's correction (the issue's "within 1 cm in the ideal
    # profile"), not the realistic picture's (docs/sim.md: its board's inset is not the lab markers');
    # the camera searches every frame and the localizer publishes at 20 Hz, resting or not (issue 35's
    # rest): the median is over as many detections as before
    where = (f'[sim]\nprofile = "ideal"\nstart_x = {x}\nstart_y = {y}\nstart_theta = {theta}\nseed = 3\n'
             f'[camera]\ncalibration = ""\nrest_detection_rate_hz = 15.0\n'
             f"[localizer]\ninitial_x = {x}\ninitial_y = {y}\ninitial_theta = {theta}\nrest_rate_hz = 20.0\n")
    robot = make_robot(where)
    stack = [robot.start(s) for s in ("sim", "hwbridge", "odometry")]  # one robot for both runs
    plain = await watch(robot)
    # the nominal lens (what the ideal profile's camera has) and the inset measured from the calibration
    # world's DICT_4X4_50 ChArUco board, as `icefloe calibrate --keep-intrinsics` would write them
    calibrate_camera(config_mod.parse({"sim": {"profile": "ideal"}}), tmp_path / "camera.yaml", seed=7)
    text = robot.config_path.read_text()  # the camera started next reads it
    robot.config_path.write_text(text.replace('calibration = ""', f'calibration = "{tmp_path / "camera.yaml"}"'))
    undone = await watch(robot)
    check_exits(stack)
    print(f"\nlocalizer at rest, median over {HOLD_S:.0f} s: as detected {plain[0] * 100:.2f} cm "
          f"{math.degrees(plain[1]):.2f} deg; inset undone {undone[0] * 100:.2f} cm {math.degrees(undone[1]):.2f} deg")
    assert undone[0] < 0.010 and math.degrees(undone[1]) < 0.5
