"""viz shows the map maker's map and SLAM's estimate with covariance ellipses (a real viz process,
its .rrd read back). ~20 s."""

from __future__ import annotations

import asyncio
import math
import time

import numpy as np
from conftest import wait_for

from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.viz.logging_rr import landmark_ellipse
from icefloe.services.viz.readback import read_rrd


def test_landmark_ellipse_has_the_95_percent_radii() -> None:
    outline = landmark_ellipse(1.0, 2.0, [0.04, 0.0, 0.0, 0.01])
    r = np.linalg.norm(outline - [1.0, 2.0], axis=1)
    assert math.isclose(r.max(), math.sqrt(5.991 * 0.04), rel_tol=1e-2)
    assert math.isclose(r.min(), math.sqrt(5.991 * 0.01), rel_tol=2e-2)


async def test_viz_records_the_reference_map_and_the_slam_estimate(robot, tmp_path) -> None:
    out = tmp_path / "out.rrd"
    viz = robot.start_module("icefloe.services.viz", "--save", str(out))
    lm = [m.MapLandmark(id=i, x=float(i), y=1.0, covariance=[0.001, 0.0, 0.0, 0.002]) for i in range(3)]
    async with robot.node("tester") as node:
        await wait_for(lambda: "showing robot" in viz.output, timeout=60)
        pose, slam_map, ref = (node.publisher(t) for t in (keys.SLAM_POSE, keys.SLAM_MAP, keys.MAP_LANDMARKS))
        for k in range(30):
            stamp = time.time_ns()
            pose.put(m.PoseEstimate(stamp=stamp, x=0.01 * k, y=0.0, theta=0.0,
                                    covariance=[1e-4, 0, 0, 0, 1e-4, 0, 0, 0, 1e-3]))
            slam_map.put(m.LandmarkMap(stamp=stamp, landmarks=lm))
            ref.put(m.LandmarkMap(stamp=stamp, landmarks=lm[:2]))
            await asyncio.sleep(0.1)
    assert viz.stop() == 0, viz.output
    data = read_rrd(out)
    root = f"/robots/{robot.name}"
    for entity in ("map/slam", "map/slam/covariance", "map/slam/landmarks", "map/slam/landmarks/covariance",
                   "map/reference", "map/reference/covariance"):
        assert data.get(f"{root}/{entity}", {}).get("log_time"), f"{entity} missing from the recording"
    assert len(data[f"{root}/map/slam/landmarks"]["Points2D:positions"][-1]) == 3
    assert len(data[f"{root}/map/reference/covariance"]["LineStrips2D:strips"][-1]) == 2
