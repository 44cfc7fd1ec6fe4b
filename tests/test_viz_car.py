"""viz draws the virtual car of ``cmd/car`` (``car/state``) on the map: its body at the bicycle
model's pose and its front wheels at the steering angle (Ackermann: about the model's one turning
centre), live (a viz process, the .rrd read back) and from a recording (``icefloe viz FILE.mcap``);
a ``car/state`` that is not one is dropped with one line and viz keeps drawing. ~8 s."""

from __future__ import annotations

import asyncio
import math

import msgspec
import numpy as np
import pytest
import rerun as rr
from conftest import wait_for

from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m
from icefloe.services.viz.logging_rr import RobotLogger, car_outline
from icefloe.services.viz.readback import read_rrd

L, TRACK = 0.15, 0.156


def axis_through(wheel: np.ndarray, centre: tuple[float, float]) -> float:
    """How far (m) the line through the wheel's middle, square to the wheel, passes from ``centre``."""
    mid, along = wheel.mean(axis=0), wheel[1] - wheel[0]
    to_centre = np.asarray(centre) - mid
    return abs(float(np.dot(to_centre, along / np.linalg.norm(along))))


@pytest.mark.parametrize("steer", [0.3, -0.5, 0.6])
def test_the_front_wheels_turn_about_the_bicycle_models_centre(steer: float) -> None:
    """At the origin facing +x: the body spans the wheelbase (and a fifth of it each end) and the
    track; the rear wheels point ahead; each front wheel's axis passes through the turning centre
    (0, L / tan(steer)), the inner wheel turned more than ``steer``, the outer less."""
    body, (rear_left, rear_right, front_left, front_right) = car_outline(0.0, 0.0, 0.0, steer, L, TRACK)
    assert body[:, 0].min() == pytest.approx(-0.2 * L) and body[:, 0].max() == pytest.approx(1.2 * L)
    assert body[:, 1].min() == pytest.approx(-TRACK / 2) and body[:, 1].max() == pytest.approx(TRACK / 2)
    assert (body[0] == body[-1]).all()
    for rear in (rear_left, rear_right):
        assert rear[1][1] == pytest.approx(rear[0][1])  # straight ahead
    centre = (0.0, L / math.tan(steer))
    angles = []
    for front in (front_left, front_right):
        assert axis_through(front, centre) == pytest.approx(0.0, abs=1e-9)
        d = front[1] - front[0]
        angles.append(math.atan2(d[1], d[0]))
    inner, outer = (angles[0], angles[1]) if steer > 0 else (angles[1], angles[0])
    assert abs(inner) > abs(steer) > abs(outer) and math.copysign(1, outer) == math.copysign(1, steer)


def test_the_car_is_where_its_pose_says_and_straight_wheels_at_zero_steer() -> None:
    body, wheels = car_outline(1.0, 2.0, math.pi / 2, 0.0, L, TRACK)
    # heading +y: the front axle is L ahead, at (1.0, 2.0 + L); its wheels point along +y
    front_left = wheels[2]
    assert front_left.mean(axis=0) == pytest.approx([1.0 - TRACK / 2, 2.0 + L])
    assert front_left[1][0] == pytest.approx(front_left[0][0])
    assert body[:, 1].max() == pytest.approx(2.0 + 1.2 * L)


def car_rows(path, robot: str) -> dict:
    return read_rrd(path).get(f"/robots/{robot}/map/car", {})


def test_a_logged_car_is_its_outline_and_its_label(tmp_path) -> None:
    out = tmp_path / "car.rrd"
    rec = rr.RecordingStream("icefloe-test")
    rec.save(out)
    logger = RobotLogger(rec, "r1", car_size=(0.2, 0.16))
    logger.car(m.CarState(stamp=1_000_000_000, v=0.2, steer=0.3, steer_target=0.3, x=0.5, y=0.1, theta=0.4,
                          driving=True))
    rec.flush()
    rec.disconnect()
    drawn = car_rows(out, "r1")
    assert len(drawn["stamp"]) == 1
    strips = drawn["LineStrips2D:strips"][0]
    body, wheels = car_outline(0.5, 0.1, 0.4, 0.3, 0.2, 0.16)
    assert len(strips) == 5
    assert np.allclose(strips[0], body, atol=1e-6)
    assert np.allclose(strips[3], wheels[2], atol=1e-6)
    assert "car 0.20 m/s +17°" in drawn["LineStrips2D:labels"][0]


def test_a_recording_played_in_viz_draws_the_car_with_the_configs_wheelbase(tmp_path) -> None:
    from icefloe import config as config_mod
    from icefloe.bag import Bag
    from icefloe.bag.writer import BagWriter
    from icefloe.services.viz.options import VizOptions
    from icefloe.services.viz.playback import show

    config = config_mod.load()
    run = tmp_path / "run.mcap"
    writer = BagWriter(run)
    for i in range(5):
        state = m.CarState(stamp=(i + 1) * 100_000_000, v=0.2, steer=-0.1 * i, steer_target=-0.4, x=0.02 * i,
                           y=0.0, theta=0.0, driving=True)
        writer.write(keys.key("r1", keys.CAR_STATE), codec.encode(state), "application/msgpack", state.stamp)
    writer.close()
    out = tmp_path / "played.rrd"
    assert show(Bag([run]), config, VizOptions(save=str(out))) == 5
    drawn = car_rows(out, "r1")
    assert len(drawn["stamp"]) == 5  # a recording is drawn whole, not thinned
    body, wheels = car_outline(0.08, 0.0, 0.0, -0.4, config.car.wheelbase, config.geometry.track)
    assert np.allclose(drawn["LineStrips2D:strips"][-1][0], body, atol=1e-6)
    assert np.allclose(drawn["LineStrips2D:strips"][-1][4], wheels[3], atol=1e-6)


async def test_viz_draws_the_car_live_and_drops_a_state_it_cannot_draw(make_robot, tmp_path) -> None:
    """A viz process and the robot's info service (wheelbase 0.2 m here); the test publishes
    ``car/state`` as hwbridge does, then a non-finite one and bad bytes: each dropped with a line
    naming the key (the non-finite one naming the field), and the car after them is drawn."""
    robot = make_robot("[car]\nwheelbase = 0.2\n")
    out = tmp_path / "live.rrd"
    robot.start("info")
    async with robot.node("tester") as node:
        viz = robot.start_module("icefloe.services.viz", "--save", str(out))
        await wait_for(lambda: "showing robot" in viz.output, timeout=20)
        states = node.publisher(keys.CAR_STATE)
        stamp = 1_000_000_000

        def put(**fields) -> None:
            nonlocal stamp
            stamp += 100_000_000  # 10 Hz: under viz's 20 Hz, none thinned out
            states.put(m.CarState(stamp=stamp, v=0.2, steer_target=0.3, y=0.0, theta=0.0, driving=True,
                                  **{"steer": 0.3, "x": 0.0, **fields}))

        for i in range(10):
            put(x=0.02 * i)
            await asyncio.sleep(0.05)
        bad = {"stamp": stamp, "v": 0.2, "steer": 0.3, "steer_target": 0.3, "x": float("inf"), "y": 0.0,
               "theta": 0.0}
        # viz draws the newest state of each key: a second one sent at once could replace the first
        # before it was read, so each bad one is seen dropped before the next is sent
        node.session.put(node.key(keys.CAR_STATE), msgspec.msgpack.encode(bad))
        await wait_for(lambda: "finite" in viz.output, timeout=20)
        node.session.put(node.key(keys.CAR_STATE), b"\xc1 not msgpack")
        await wait_for(lambda: "not valid MessagePack" in viz.output, timeout=20)
        put(x=0.5, steer=-0.2)
        await asyncio.sleep(1.0)
    assert viz.alive(), viz.output
    assert viz.stop() == 0, viz.output
    dropped = [line for line in viz.output.splitlines() if "car/state" in line and "dropped" in line]
    assert any("`x`" in line and "finite" in line for line in dropped), viz.output
    assert len(dropped) == 2, viz.output
    drawn = car_rows(out, robot.name)
    assert 8 <= len(drawn["stamp"]) <= 11, drawn["stamp"]
    body, wheels = car_outline(0.5, 0.0, 0.0, -0.2, 0.2, robot.config.geometry.track)
    assert np.allclose(drawn["LineStrips2D:strips"][-1][0], body, atol=1e-6)
    assert np.allclose(drawn["LineStrips2D:strips"][-1][4], wheels[3], atol=1e-6)
