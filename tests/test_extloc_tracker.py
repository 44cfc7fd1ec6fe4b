"""The lab's localizer between frames (services/extloc/tracker.py), pure logic: the lab's config
read and checked, the camera's pose found from the floor in the first frame, each robot's pose
from the simulator's picture. No bus, no processes (a few seconds)."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT

from icefloe import config as config_mod
from icefloe.angles import wrap_angle
from icefloe.config import RobotConfig
from icefloe.errors import ConfigError
from icefloe.schemas import messages as m
from icefloe.services.extloc.sources import SimOverheadSource
from icefloe.services.extloc.tracker import OverheadLocalizer, groups

TRUTHS = {"r1": (0.4, 0.3, 1.0), "r2": (-0.9, 0.6, -2.5)}


def lab(tmp_path: Path, extloc: dict[str, str] | None = None) -> RobotConfig:
    """A lab config whose ``overhead.robots`` are robots r1 and r2 (top markers 20, 21); ``extloc``:
    more lines for a robot's ``[extloc]``."""
    paths = []
    for i, name in enumerate(TRUTHS):
        path = tmp_path / f"{name}.toml"
        path.write_text(f'extends = "{ROOT / "deploy/robots/sim.toml"}"\nname = "{name}"\n\n[extloc]\n'
                        f"marker_id = {20 + i}\nmarker_size = 0.16\nmarker_height = 0.12\n"
                        + (extloc or {}).get(name, ""))
        paths.append(str(path))
    path = tmp_path / "lab.toml"
    path.write_text(f'name = "lab"\n\n[overhead]\nrobots = {json.dumps(paths)}\n')
    return config_mod.load(str(path))


def picture(config: RobotConfig, tracker: OverheadLocalizer) -> np.ndarray:
    """The simulated overhead camera's frame of the robots at TRUTHS (its own, unpaced renderer)."""
    sim = SimOverheadSource(config.overhead, tracker.robots)
    for name, (x, y, theta) in TRUTHS.items():
        sim.set_truth(name, m.Truth(stamp=1, x=x, y=y, theta=theta))
    return sim.renderer.render(sim.views())


def test_the_first_frame_finds_the_camera_from_the_floor_then_every_robot_its_pose(tmp_path, caplog) -> None:
    config = lab(tmp_path)
    tracker = OverheadLocalizer(config, logging.getLogger("icefloe.extloc"))
    assert tracker.locator is None  # no overhead.pose: found from the floor markers
    assert tracker.group_of == {1: "r1", 2: "r2"}
    caplog.set_level(logging.INFO, logger="icefloe.extloc")
    poses = dict(tracker.on_frame(123, picture(config, tracker)))
    assert tracker.locator is not None and "overhead camera found from floor markers" in caplog.text
    assert set(poses) == set(TRUTHS)
    for name, (x, y, theta) in TRUTHS.items():
        pose = poses[name]
        assert pose.stamp == 123
        assert math.hypot(pose.x - x, pose.y - y) < 0.01 and abs(wrap_angle(pose.theta - theta)) < math.radians(1)
        assert pose.covariance[0] == pose.covariance[4] > 0 and pose.covariance[8] > 0


def test_a_frame_without_the_floor_leaves_the_camera_unknown_and_says_why(tmp_path, caplog) -> None:
    config = lab(tmp_path)
    tracker = OverheadLocalizer(config, logging.getLogger("icefloe.extloc"))
    caplog.set_level(logging.INFO, logger="icefloe.extloc")
    dark = np.zeros((config.overhead.height, config.overhead.width, 3), np.uint8)
    assert tracker.on_frame(1, dark) == [] and tracker.locator is None
    assert "cannot find the overhead camera's pose yet" in caplog.text


def test_a_lab_without_robots_or_with_a_group_twice_is_refused_by_name(tmp_path) -> None:
    empty = tmp_path / "empty.toml"
    empty.write_text('name = "lab"\n[overhead]\nrobots = []\n')
    with pytest.raises(ConfigError, match=r"overhead\.robots: no robots to look for"):
        OverheadLocalizer(config_mod.load(str(empty)), logging.getLogger("icefloe.extloc"))
    config = lab(tmp_path, {"r2": "group = 1\n"})
    robots = [config_mod.load(name) for name in config.overhead.robots]
    with pytest.raises(ConfigError, match="group 1 is both r1's and r2's"):
        groups(robots, config.source)
